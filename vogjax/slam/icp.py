"""ICP between submap point clouds: the thesis's 2D point-to-point (x, y, yaw; Ho, Algorithm 6)
and point-to-plane with degeneracy-aware updates (Zhang et al.'s solution remapping; Ho,
Algorithm 7). Nearest neighbours come from a k-d tree; the normal equations are batched NumPy.

The Hessian reported is the Gauss-Newton J^T J of point-to-plane residuals at the result (with
respect to GTSAM's Pose3 tangent of T_target_source: rotation, then translation), so both
methods tell how well each direction is constrained; `basis` holds the eigenvectors whose
eigenvalue reaches `lambda_min` per inlier.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from vogjax.geometry import rigid_poses


@dataclasses.dataclass(frozen=True)
class IcpConfig:
    max_iterations: int = 50
    max_correspondence_m: float = 1.0  # pairs farther apart are outliers
    tolerance: float = 1e-6  # stop when an update moves less than this (rad and m)
    normal_neighbours: int = 10  # target points used to fit each normal
    # Directions whose eigenvalue of J^T J is below lambda_min times the number of inliers are
    # degenerate (per inlier, so the threshold does not depend on the cloud's size; a unit
    # normal contributes at most 1 to a translation direction).
    lambda_min: float = 0.01
    min_inliers: int = 10


@dataclasses.dataclass(frozen=True)
class IcpResult:
    """T_target_source (4,4); converged; fitness: mean squared inlier distance (m^2);
    num_inliers; hessian (6,6); eigenvalues (6,) ascending with eigenvectors (6,6) as columns;
    basis (6,r): the directions with eigenvalue >= lambda_min * num_inliers (r = 6: nothing
    degenerate)."""

    T_target_source: np.ndarray
    converged: bool
    fitness: float
    num_inliers: int
    iterations: int
    hessian: np.ndarray
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    basis: np.ndarray

    @property
    def degenerate(self) -> bool:
        return self.basis.shape[1] < 6


def _skew(p: np.ndarray) -> np.ndarray:
    """(N,3,3) cross-product matrices."""
    z = np.zeros(len(p))
    return np.stack([np.stack([z, -p[:, 2], p[:, 1]], -1), np.stack([p[:, 2], z, -p[:, 0]], -1),
                     np.stack([-p[:, 1], p[:, 0], z], -1)], axis=1)


def _exp(xi: np.ndarray) -> np.ndarray:
    """SE(3) exponential of (omega, v) (rotation by Rodrigues, translation by V)."""
    omega, v = xi[:3], xi[3:]
    theta = np.linalg.norm(omega)
    W = _skew(omega[None])[0]
    if theta < 1e-10:
        R, V = np.eye(3) + W, np.eye(3) + 0.5 * W
    else:
        a, b = np.sin(theta) / theta, (1 - np.cos(theta)) / theta**2
        R = np.eye(3) + a * W + b * W @ W
        V = np.eye(3) + b * W + (theta - np.sin(theta)) / theta**3 * W @ W
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, V @ v
    return T


def target_normals(target: np.ndarray, tree: cKDTree, neighbours: int) -> np.ndarray:
    """Unit normals of the target cloud: smallest principal axis of each point's neighbours."""
    k = min(neighbours, len(target))
    _, index = tree.query(target, k=k)
    patches = target[index.reshape(len(target), k)]
    centred = patches - patches.mean(axis=1, keepdims=True)
    _, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
    return vectors[:, :, 0]


def _plane_system(source_moved, R, source, target_points, normals):
    """J (N,6) and residuals (N,) of point-to-plane errors n . (T p - q)."""
    residuals = np.einsum("ni,ni->n", normals, source_moved - target_points)
    d_omega = -np.einsum("ni,ij,njk->nk", normals, R, _skew(source))  # n^T R (-[p]x)
    d_v = normals @ R
    return np.concatenate([d_omega, d_v], axis=1), residuals


def icp(source, target, T_init=None, method: str = "point_to_plane",
        config: IcpConfig | None = None) -> IcpResult:
    """Align `source` (N,3) to `target` (M,3), starting from T_init (4,4) T_target_source."""
    config = config or IcpConfig()
    source = _cloud("source", source)
    target = _cloud("target", target)
    T = rigid_poses("T_init", np.eye(4) if T_init is None else T_init)[0].copy()
    if method not in ("point_to_plane", "point_to_point_xyh"):
        raise ValueError(f"method must be 'point_to_plane' or 'point_to_point_xyh', got {method!r}")
    tree = cKDTree(target)
    normals = target_normals(target, tree, config.normal_neighbours)
    converged, iterations = False, 0
    for iterations in range(1, config.max_iterations + 1):
        moved = source @ T[:3, :3].T + T[:3, 3]
        distance, index = tree.query(moved, distance_upper_bound=config.max_correspondence_m)
        inlier = np.isfinite(distance)
        if inlier.sum() < config.min_inliers:
            break
        p, q = source[inlier], target[index[inlier]]
        if method == "point_to_point_xyh":
            step = _xyh_step(moved[inlier], q)
        else:
            J, r = _plane_system(moved[inlier], T[:3, :3], p, q, normals[index[inlier]])
            H, g = J.T @ J, J.T @ r
            values, vectors = np.linalg.eigh(H)
            good = values >= config.lambda_min * len(r)
            if not good.any():
                break
            # Solve only in the well-conditioned eigen-directions; leave the others as they are.
            xi = -vectors[:, good] @ ((vectors[:, good].T @ g) / values[good])
            step = T @ _exp(xi) @ np.linalg.inv(T)
        T = step @ T
        change = np.linalg.norm(step[:3, 3]) + np.arccos(np.clip((np.trace(step[:3, :3]) - 1) / 2, -1, 1))
        if change < config.tolerance:
            converged = True
            break
    return _result(source, target, tree, normals, T, converged, iterations, config)


def _xyh_step(moved: np.ndarray, matched: np.ndarray) -> np.ndarray:
    """Best 2D rigid motion (x, y, yaw) of `moved` onto `matched` in the world x-y plane."""
    a, b = moved[:, :2], matched[:, :2]
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    rotation = (u @ vt).T
    if np.linalg.det(rotation) < 0:
        vt[-1] *= -1
        rotation = (u @ vt).T
    step = np.eye(4)
    step[:2, :2] = rotation
    step[:2, 3] = cb - rotation @ ca
    return step


def _result(source, target, tree, normals, T, converged, iterations, config) -> IcpResult:
    moved = source @ T[:3, :3].T + T[:3, 3]
    distance, index = tree.query(moved, distance_upper_bound=config.max_correspondence_m)
    inlier = np.isfinite(distance)
    if inlier.any():
        J, _ = _plane_system(moved[inlier], T[:3, :3], source[inlier], target[index[inlier]],
                             normals[index[inlier]])
        H = J.T @ J
        fitness = float(np.mean(distance[inlier] ** 2))
    else:
        H, fitness = np.zeros((6, 6)), float("inf")
    values, vectors = np.linalg.eigh(H)
    num_inliers = int(inlier.sum())
    good = values >= config.lambda_min * max(num_inliers, 1)
    return IcpResult(T, bool(converged and num_inliers >= config.min_inliers), fitness, num_inliers,
                     iterations, H, values, vectors, vectors[:, good])


def _cloud(name: str, value) -> np.ndarray:
    try:
        cloud = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an (N, 3) point cloud") from None
    if cloud.ndim != 2 or cloud.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {cloud.shape}")
    if len(cloud) < 3:
        raise ValueError(f"{name} needs at least 3 points, got {len(cloud)}")
    if not np.all(np.isfinite(cloud)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return cloud
