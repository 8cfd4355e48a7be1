"""ICP between submap point clouds: the thesis's 2D point-to-point (x, y, yaw; Ho, Algorithm 6)
and point-to-plane with degeneracy-aware updates (Zhang et al.'s solution remapping; Ho,
Algorithm 7). Nearest neighbours come from a k-d tree (or, on a Warp device, a hash grid: the
same neighbours); the normal equations are NumPy (with the rotation held, the translation's
3 x 3 alone, per pair), their eigen-decompositions batched over the pairs. A target's tree and
normals can be prepared once (`prepare_target`) and reused.

The Hessian reported is the Gauss-Newton J^T J of point-to-plane residuals at the result (with
respect to GTSAM's Pose3 tangent of T_target_source: rotation, then translation), so both
methods tell how well each direction is constrained. Which directions are constrained is
decided in the tangent at the source cloud's centroid, where a turn of the cloud and a shift
of it are told apart: in the tangent at the source frame's origin, a cloud 30 m from it turns
about its own centre by a twist of rotation and 30 times as much translation, whose
eigenvalue per inlier falls below `lambda_min` although the cloud fixes it well (a converged
alignment 0.1 m and 0.2 degrees off on exact data). `basis` holds the directions whose
eigenvalue there reaches `lambda_min` per inlier, in GTSAM's tangent.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
import warp as wp
from scipy.spatial import cKDTree

from vogjax import devices
from vogjax.config import IcpConfig
from vogjax.geometry import exp_se3, rigid_poses, skew
from vogjax.kernels import registration
from vogjax.maps import parallel
from vogjax.validation import real_array

MAX_COORDINATE_M = 1e7  # clouds farther out lose their metres in float64 squares
MIN_POINTS = 3  # fewer cannot fix a pose


@dataclasses.dataclass(frozen=True)
class IcpResult:
    """What one ICP alignment found, and how well each direction is constrained.

    Attributes
    ----------
    T_target_source : (4, 4) ndarray of float64
        The alignment: maps source points into the target's frame.
    converged : bool
        An update moved less than `IcpConfig.tolerance` within `max_iterations`, with at least
        `min_inliers` inliers at the result.
    fitness : float
        Mean squared distance of the inliers to their nearest target points at the result,
        m^2; inf when there are none.
    num_inliers : int
        Source points with a target point strictly within `max_correspondence_m` at the result.
    iterations : int
        Iterations run.
    hessian : (6, 6) ndarray of float64
        Gauss-Newton J^T J of the point-to-plane residuals at the result, with respect to
        GTSAM's Pose3 tangent of T_target_source (rotation, then translation), whichever the
        method; a direction ICP held at `centre` (`IcpConfig.free`, and z, roll and pitch for
        "point_to_point_xyh") contributes nothing.
    eigenvalues : (6,) ndarray of float64
        The eigenvalues, ascending, of the same J^T J in the tangent at `centre`: of
        ``T_target_source @ T_centre`` (``T_centre`` the translation by `centre`), whose twists
        `centre_adjoint` takes to GTSAM's tangent.
    eigenvectors : (6, 6) ndarray of float64
        The matching eigenvectors, as columns, in the tangent at `centre`.
    basis : (6, r) ndarray of float64
        Orthonormal columns spanning the eigenvectors whose eigenvalue reaches ``lambda_min *
        num_inliers`` (the well-constrained directions; r = 6: nothing degenerate), as
        directions of GTSAM's tangent (`constrained_basis`).
    centre : (3,) ndarray of float64
        The source cloud's centroid, in the source frame, metres: where the constrained
        directions are judged; zero when the rotation is held (point-to-plane, free
        "translation"), where it makes no difference.
    """

    T_target_source: npt.NDArray[np.float64]
    converged: bool
    fitness: float
    num_inliers: int
    iterations: int
    hessian: npt.NDArray[np.float64]
    eigenvalues: npt.NDArray[np.float64]
    eigenvectors: npt.NDArray[np.float64]
    basis: npt.NDArray[np.float64]
    centre: npt.NDArray[np.float64]

    @property
    def degenerate(self) -> bool:
        """Whether some direction is not well constrained (`basis` has fewer than 6 columns)."""
        return self.basis.shape[1] < 6


@dataclasses.dataclass(frozen=True)
class IcpTarget:
    """A target cloud prepared for ICP once, for as many alignments as it takes part in.

    Make it with `prepare_target`: `icp_batch` refuses one whose parts do not belong together.

    Attributes
    ----------
    points : (M, 3) ndarray of float64
        The target's distinct points, metres (read-only), in their order (a repeated point
        kept where it first appears).
    tree : scipy.spatial.cKDTree
        Their k-d tree.
    normals : (M, 3) ndarray of float64
        Their unit normals (read-only), each the smallest principal axis of its `neighbours`
        nearest points.
    neighbours : int
        The points each normal was fitted to (`IcpConfig.normal_neighbours`).
    """

    points: npt.NDArray[np.float64]
    tree: cKDTree
    normals: npt.NDArray[np.float64]
    neighbours: int


def prepare_target(target: npt.ArrayLike, config: IcpConfig | None = None) -> IcpTarget:
    """Check a target cloud and fit its k-d tree and normals, once for many alignments.

    Parameters
    ----------
    target : (M, 3) array_like of float
        The target cloud, metres; at least 3 points, finite, within 1e7 m of the origin.
    config : IcpConfig or None, optional
        ICP settings: `normal_neighbours` is read (default: ``IcpConfig()``).

    Returns
    -------
    IcpTarget
        A copy of the distinct points, with their tree and normals.

    Raises
    ------
    ValueError
        If `target` is not an (M, 3) array of real numbers, has fewer than 3 distinct points,
        NaN or infinite values, or coordinates beyond 1e7 m.
    """
    config = config or IcpConfig()
    points = np.array(_cloud("target", target))  # a copy: the tree and normals describe these values
    # a point repeated fills its own neighbourhood with copies, whose scatter has no least axis
    # (its normal came out as whatever eigh returns for zero): each point once, in order
    _, first = np.unique(points, axis=0, return_index=True)
    if len(first) < len(points):
        points = points[np.sort(first)]
        if len(points) < MIN_POINTS:
            raise ValueError(f"target needs at least {MIN_POINTS} distinct points, got {len(points)}")
    points.setflags(write=False)
    tree = cKDTree(points)
    normals = target_normals(points, tree, config.normal_neighbours)
    normals.setflags(write=False)
    return IcpTarget(points, tree, normals, config.normal_neighbours)


def _check_target(target: IcpTarget, config: IcpConfig) -> IcpTarget:
    """A prepared target as `prepare_target` makes them (one built by hand could pair a tree
    or normals with other points)."""
    points = target.points
    if not (
        isinstance(points, np.ndarray)
        and points.dtype == np.float64
        and points.ndim == 2
        and points.shape[1] == 3
        and len(points) >= 3
        and isinstance(target.tree, cKDTree)
        and target.tree.n == len(points)
        and np.array_equal(target.tree.data, points)
        and isinstance(target.normals, np.ndarray)
        and target.normals.shape == points.shape
    ):
        raise ValueError(
            "targets: an IcpTarget whose points, tree and normals do not belong together "
            "(make them with prepare_target)"
        )
    lengths = np.linalg.norm(target.normals, axis=1)
    if not np.all(np.abs(lengths - 1.0) <= 1e-6):  # (NaN fails too) zero normals "converged" unmoved
        raise ValueError("targets: an IcpTarget's normals must be finite unit vectors (make them with prepare_target)")
    if target.neighbours != config.normal_neighbours:
        raise ValueError("targets: an IcpTarget was prepared with other normal_neighbours than config's")
    return target


def target_normals(target: np.ndarray, tree: cKDTree, neighbours: int) -> np.ndarray:
    """Unit normals of the target cloud: smallest principal axis of each point's neighbours.

    A cloud of THREADED_NORMAL_POINTS or more (a lidar's submap or local map) is done in two
    halves on the launch pool's threads (the queries and eigh release the GIL): the same
    neighbours and the same bits, 46-60 against 31-32 ms on a 14,600-point local map."""
    k = min(neighbours, len(target))

    def normals(rows: slice) -> np.ndarray:
        _, index = tree.query(target[rows], k=k)
        patches = target[index.reshape(-1, k)]
        centred = patches - patches.mean(axis=1, keepdims=True)
        return np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))[1][:, :, 0]

    if len(target) < THREADED_NORMAL_POINTS:
        return normals(slice(None))
    half = len(target) // 2
    return np.concatenate(list(parallel.ordered_map(normals, [slice(0, half), slice(half, None)])))


def _plane_system(moved, rotation, source, matched, normals):
    """J (..., N, 6) and residuals (..., N) of point-to-plane errors n . (T p - q); `rotation`
    (..., 3, 3) is T's."""
    residuals = np.einsum("...ni,...ni->...n", normals, moved - matched)
    n_rotated = np.einsum("...ni,...ij->...nj", normals, rotation)  # n^T R
    J = np.empty((*n_rotated.shape[:-1], 6))
    # n^T R (-[p]x) = (p x R^T n)^T, the cross product as np.cross forms it (the same bits,
    # without its axis handling, which cost a sonar run's ICP a tenth of its time)
    p0, p1, p2 = source[..., 0], source[..., 1], source[..., 2]
    r0, r1, r2 = n_rotated[..., 0], n_rotated[..., 1], n_rotated[..., 2]
    J[..., 0] = p1 * r2 - p2 * r1
    J[..., 1] = p2 * r0 - p0 * r2
    J[..., 2] = p0 * r1 - p1 * r0
    J[..., 3:] = n_rotated
    return J, residuals


def icp(
    source: npt.ArrayLike,
    target: npt.ArrayLike | IcpTarget,
    T_init: npt.ArrayLike | None = None,
    method: str = "point_to_plane",
    config: IcpConfig | None = None,
) -> IcpResult:
    """Align a source cloud to a target cloud (`icp_batch` for one pair).

    Parameters
    ----------
    source : (N, 3) array_like of float
        The source cloud, metres; at least 3 points.
    target : (M, 3) array_like of float or IcpTarget
        The target cloud, metres, or one prepared by `prepare_target`.
    T_init : (4, 4) array_like of float or None, optional
        Where to start: ``T_target_source``, a rigid transform (None: the identity).
    method : {"point_to_plane", "point_to_point_xyh"}, optional
        Point-to-plane with degeneracy-aware updates (Ho, Algorithm 7), or the 2D
        point-to-point x, y, yaw of Ho's Algorithm 6.
    config : IcpConfig or None, optional
        ICP settings (default: ``IcpConfig()``).

    Returns
    -------
    IcpResult
        The alignment ``T_target_source``, whether it converged, its fitness, and how well each
        direction is constrained.

    Raises
    ------
    ValueError
        As for `icp_batch`.
    """
    T_inits = None if T_init is None else rigid_poses("T_init", T_init, count=None)
    if T_inits is not None and len(T_inits) != 1:
        raise ValueError(f"T_init must be one (4, 4) rigid transform, got shape {np.shape(T_init)}")
    return icp_batch([source], [target], T_inits, method, config)[0]


def icp_batch(
    sources: Sequence[npt.ArrayLike],
    targets: Sequence[npt.ArrayLike | IcpTarget],
    T_inits: npt.ArrayLike | None = None,
    method: str = "point_to_plane",
    config: IcpConfig | None = None,
    device: str | wp.Device | None = None,
) -> list[IcpResult]:
    """Align many (source, target) pairs at once.

    The neighbour searches run per pair, the eigen-decompositions and updates for all pairs
    together. A target may be an `IcpTarget` (`prepare_target`): its tree and normals are used
    as they are, so a cloud that is a target many times is prepared once, with the same
    results.

    With the rotation held (point-to-plane, free="translation") each source is turned by its
    T_init once and only the translation is solved for (3 x 3 normal equations per pair; the
    rotation stays T_init's bit for bit), and a pair whose correspondences can only cycle stops
    there, unconverged, before max_iterations (why: `_translation_only`).

    device None: each iteration's nearest neighbours from the k-d trees. A Warp device (a CUDA
    GPU; "cpu" runs the same kernel on the host): from one hash grid over every target, all
    pairs in one launch. Both find the nearest point strictly within max_correspondence_m, so
    the results are the same but where two target points are equally near (the tree may pick
    either; the grid picks the lower index).

    Parameters
    ----------
    sources : sequence of (N_p, 3) array_like of float
        The source clouds, metres; at least 3 points each, finite, within 1e7 m of the origin.
    targets : sequence of (M_p, 3) array_like of float or IcpTarget
        One target per source, as clouds or prepared by `prepare_target` (with this config's
        `normal_neighbours`).
    T_inits : (P, 4, 4) array_like of float or None, optional
        Where each pair starts: ``T_target_source``, rigid transforms (None: the identity).
    method : {"point_to_plane", "point_to_point_xyh"}, optional
        As for `icp`.
    config : IcpConfig or None, optional
        ICP settings (default: ``IcpConfig()``).
    device : str or warp.Device or None, optional
        Where the nearest neighbours are found: None, the k-d trees; a Warp device, one hash
        grid.

    Returns
    -------
    list of IcpResult
        One per pair, in order.

    Raises
    ------
    ValueError
        If `method` is unknown, `sources` and `targets` differ in length, a cloud is not an
        (N, 3) array of real numbers with at least 3 points, finite and within 1e7 m, an
        IcpTarget's parts do not belong together or were prepared with other
        `normal_neighbours`, `T_inits` are not one rigid transform per pair, or `device` is
        not available.
    """
    config = config or IcpConfig()
    if method not in ("point_to_plane", "point_to_point_xyh"):
        raise ValueError(f"method must be 'point_to_plane' or 'point_to_point_xyh', got {method!r}")
    device = None if device is None else devices.resolve(device)
    if len(sources) != len(targets):
        raise ValueError("sources and targets must pair up (same length)")
    sources = [_cloud("source", c) for c in sources]
    prepared = [_check_target(t, config) if isinstance(t, IcpTarget) else prepare_target(t, config) for t in targets]
    count = len(sources)
    T = np.tile(np.eye(4), (count, 1, 1)) if T_inits is None else rigid_poses("T_inits", T_inits, count=count).copy()
    if count == 0:
        return []
    targets = [t.points for t in prepared]
    trees = [t.tree for t in prepared]
    normals = [t.normals for t in prepared]
    nearest = (
        _tree_neighbours(trees, config.max_correspondence_m)
        if device is None
        else _GridNeighbours(targets, config.max_correspondence_m, device)
    )
    centres = _centres(sources, method, config)
    if method == "point_to_plane" and config.free == "translation":
        converged, iterations = _translation_only(sources, targets, normals, nearest, T, config)
    else:
        converged, iterations = _rigid_steps(sources, targets, normals, nearest, T, method, config, centres)
    return [
        _result(
            sources[k],
            targets[k],
            trees[k],
            normals[k],
            T[k],
            bool(converged[k]),
            int(iterations[k]),
            config,
            method,
            np.zeros(3) if centres is None else centres[k],
        )
        for k in range(count)
    ]


def _rigid_steps(
    sources: list,
    targets: list,
    normals: list,
    nearest,
    T: np.ndarray,
    method: str,
    config: IcpConfig,
    centres: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """ICP steps that may turn the source (point-to-plane with `config.free` "all" or "yaw", or
    the 2D point-to-point x, y, yaw) for every pair together on padded arrays: T (P, 4, 4)
    updated in place. Returns (converged, iterations) per pair."""
    count = len(sources)
    width = max(len(s) for s in sources)
    active = np.ones(count, bool)
    converged = np.zeros(count, bool)
    iterations = np.zeros(count, int)
    for _ in range(config.max_iterations):
        ids = np.flatnonzero(active)
        if len(ids) == 0:
            break
        # correspondences, per pair, into padded arrays (weight 0 marks padding and outliers)
        p = np.zeros((len(ids), width, 3))
        q, n, moved = np.zeros_like(p), np.zeros_like(p), np.zeros_like(p)
        weight = np.zeros((len(ids), width))
        moved_points = [sources[pair] @ T[pair, :3, :3].T + T[pair, :3, 3] for pair in ids]
        for row, (pair, m, index) in enumerate(zip(ids, moved_points, nearest(ids, moved_points))):
            source = sources[pair]
            inlier = index >= 0
            size = int(inlier.sum())
            p[row, :size], moved[row, :size] = source[inlier], m[inlier]
            q[row, :size] = targets[pair][index[inlier]]
            n[row, :size] = normals[pair][index[inlier]]
            weight[row, :size] = 1.0
        inliers = weight.sum(axis=1)
        iterations[ids] += 1
        if method == "point_to_point_xyh":
            steps = _xyh_steps(moved, q, weight)
        else:
            # in the tangent at each source's centroid (the module's docstring says why)
            J, r = _plane_system(moved, T[ids, :3, :3], p - centres[ids, None, :], q, n)
            J = J * weight[..., None] * _free_columns(config)
            H = np.einsum("pni,pnj->pij", J, J)
            g = np.einsum("pni,pn->pi", J, r)
            values, vectors = np.linalg.eigh(H)
            good = values >= config.lambda_min * np.maximum(inliers, 1)[:, None]
            # Solve only in the well-conditioned eigen-directions; leave the others as they are.
            along = np.where(good, np.einsum("pji,pj->pi", vectors, g) / np.where(good, values, 1.0), 0.0)
            xi = -np.einsum("pij,pj->pi", vectors, along)
            at = T[ids] @ _translation(centres[ids])
            steps = at @ exp_se3(xi) @ np.linalg.inv(at)
        T[ids] = steps @ T[ids]
        angle = np.arccos(np.clip((np.trace(steps[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1))
        done = np.linalg.norm(steps[:, :3, 3], axis=1) + angle < config.tolerance
        starved = inliers < config.min_inliers
        converged[ids] = done & ~starved
        active[ids] = ~(done | starved)
    return converged, iterations


def _translation_only(
    sources: list, targets: list, normals: list, nearest, T: np.ndarray, config: IcpConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Point-to-plane ICP with each pair's rotation held (free "translation"): T's translations
    (P, 4, 4; updated in place) moved until a step is below the tolerance. Returns (converged,
    iterations) per pair.

    The rotation is held exactly (each source is turned once), so the normal equations are
    those of the translation alone: per pair, (n^T R)^T (n^T R) over its inliers, solved in its
    eigen-directions of at least ``lambda_min`` per inlier. Holding the rotation, a step that
    is well conditioned in x, y and z lands on the least-squares translation of the
    correspondences, wherever it started. So once a pair's correspondences come back after such
    steps only (and not from the step just before: that is a fixed point), it goes round the
    same cycle (none of its steps below the tolerance, or it would have stopped) and never
    converges: it stops there instead of at max_iterations (a third of ICP's work on a
    propeller survey)."""
    count = len(sources)
    rotations = T[:, :3, :3]
    turned = [source @ rotations[pair].T for pair, source in enumerate(sources)]
    active = np.ones(count, bool)
    converged = np.zeros(count, bool)
    iterations = np.zeros(count, int)
    cycles = [{} for _ in range(count)]
    for _ in range(config.max_iterations):
        ids = np.flatnonzero(active)
        if len(ids) == 0:
            break
        moved = [turned[pair] + T[pair, :3, 3] for pair in ids]
        H = np.zeros((len(ids), 3, 3))
        g = np.zeros((len(ids), 3))
        inliers = np.zeros(len(ids))
        matches = list(nearest(ids, moved))
        for row, (pair, points, index) in enumerate(zip(ids, moved, matches)):
            inlier = index >= 0
            matched = index[inlier]
            plane = normals[pair][matched]
            J = plane @ rotations[pair]  # d(n . (R p + t - q)) / d(translation in the source frame)
            residuals = np.einsum("ni,ni->n", plane, points[inlier] - targets[pair][matched])
            H[row], g[row], inliers[row] = J.T @ J, J.T @ residuals, len(matched)
        iterations[ids] += 1
        values, vectors = np.linalg.eigh(H)
        good = values >= config.lambda_min * np.maximum(inliers, 1)[:, None]
        # solve only in the well-conditioned eigen-directions; leave the others as they are
        along = np.where(good, np.einsum("pji,pj->pi", vectors, g) / np.where(good, values, 1.0), 0.0)
        steps = np.einsum("pij,pj->pi", rotations[ids], -np.einsum("pij,pj->pi", vectors, along))
        T[ids, :3, 3] += steps
        done = np.linalg.norm(steps, axis=1) < config.tolerance
        starved = inliers < config.min_inliers
        cycling = _returned(cycles, ids, matches, good.sum(axis=1) == 3, iterations[ids])
        converged[ids] = done & ~starved
        active[ids] = ~(done | starved | cycling)
    return converged, iterations


def _centres(sources: list, method: str, config: IcpConfig) -> np.ndarray | None:
    """Each source's centroid, where its directions are judged; None with the rotation held
    (the tangent's translation part is the same at every point: nothing changes, bit for bit)."""
    if method == "point_to_plane" and config.free == "translation":
        return None
    return np.array([source.mean(axis=0) for source in sources])


def _translation(offsets: np.ndarray) -> np.ndarray:
    """(..., 4, 4) pure translations by (..., 3) offsets."""
    T = np.zeros((*offsets.shape[:-1], 4, 4))
    T[..., :3, :3] = np.eye(3)
    T[..., :3, 3] = offsets
    T[..., 3, 3] = 1.0
    return T


def centre_adjoint(centre: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """The (6, 6) map A of twists in the tangent at `centre` to GTSAM's Pose3 tangent at
    T_target_source: ``T @ T_centre @ Exp(xi_c) @ T_centre^-1 = T @ Exp(A @ xi_c)``, the
    adjoint of the translation ``T_centre`` (a turn about the centre is a turn and a shift at
    the origin).

    Parameters
    ----------
    centre : (3,) array_like of float
        `IcpResult.centre`, metres.

    Returns
    -------
    (6, 6) ndarray of float64
        ``[[I, 0], [[centre]x, I]]`` in (rotation, translation) order.
    """
    A = np.eye(6)
    A[3:, :3] = skew(np.asarray(centre, dtype=np.float64))
    return A


def constrained_basis(result: IcpResult, directions: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Orthonormal columns, in GTSAM's tangent at T_target_source, spanning what the chosen
    eigen-directions (in the tangent at `result.centre`) constrain.

    A measurement of ``u . xi_c`` is one of ``(A^-T u) . xi``, with A = `centre_adjoint`: the
    constrained directions at the origin span A^-T times the chosen eigenvectors (not
    orthonormal; a QR makes them so, without changing what they span).

    Parameters
    ----------
    result : IcpResult
        The alignment.
    directions : (6,) array_like of bool
        Which of `result.eigenvectors` to keep.

    Returns
    -------
    (6, r) ndarray of float64
        r the number chosen; the eigenvectors themselves where the centre is zero.
    """
    chosen = result.eigenvectors[:, np.asarray(directions, dtype=bool)]
    if not result.centre.any():
        return chosen
    A_inv = np.linalg.inv(centre_adjoint(result.centre))
    return np.linalg.qr(A_inv.T @ chosen)[0]


def _returned(
    cycles: list, pairs: np.ndarray, matches: list, well_conditioned: np.ndarray, iteration: np.ndarray
) -> np.ndarray:
    """Per pair: did its correspondences (nearest indices) come back, two or more iterations
    after they were last used, since its last step that was not well conditioned?
    `cycles[pair]` remembers since then each set's digest and last iteration. The set of the
    iteration just before is no cycle but a fixed point, left to the tolerance: there the
    solve's round-off can keep a step above a tiny tolerance for one more iteration."""
    back = np.zeros(len(pairs), bool)
    for row, (pair, index) in enumerate(zip(pairs, matches)):
        if not well_conditioned[row]:
            cycles[pair].clear()  # such a step keeps part of where it started: no cycle follows
            continue
        key = hashlib.blake2b(index.tobytes(), digest_size=16).digest()
        last = cycles[pair].get(key)
        back[row] = last is not None and iteration[row] - last >= 2
        cycles[pair][key] = iteration[row]
    return back


# An ICP iteration's neighbour queries run on several threads from this many points in all
THREADED_QUERY_POINTS = 16_384
# A target's normals are fitted on two threads from this many points (a sonar swath's few
# hundred stay on one: the hand-off would cost more than it saves)
THREADED_NORMAL_POINTS = 8_192


def _tree_neighbours(trees: list, max_distance_m: float):
    """nearest(pairs, moved): per pair, the index of each moved point's nearest target point
    within max_distance_m, -1 where there is none, from the pair's k-d tree."""

    def one(pair_points):
        pair, points = pair_points
        distance, index = trees[pair].query(points, distance_upper_bound=max_distance_m)
        return np.where(np.isfinite(distance), index, -1)

    def nearest(pairs, moved):
        # the pairs' queries on the launch pool's threads where they are large (a lidar
        # submap's tens of thousands of points; a sonar swath's few hundred query faster alone)
        large = sum(len(points) for points in moved) >= THREADED_QUERY_POINTS
        return parallel.ordered_map(one, zip(pairs, moved), threaded=large)

    return nearest


class _GridNeighbours:
    """`_tree_neighbours` on a Warp device: every target in one hash grid (cells of the bound,
    so a query visits at most 4 cells per axis), the pairs told apart by the grid's groups."""

    def __init__(self, targets: list, max_distance_m: float, device):
        self.device, self.max_distance_m = device, max_distance_m
        starts = np.concatenate([[0], np.cumsum([len(t) for t in targets])])
        self.starts = starts
        with wp.ScopedDevice(device):
            self.points = wp.array(np.concatenate(targets), dtype=wp.vec3d)
            self.grid = wp.HashGrid(128, 128, 128, dtype=wp.float64)
            self.grid.build(
                self.points,
                max_distance_m,
                groups=wp.array(np.repeat(np.arange(len(targets), dtype=np.int32), np.diff(starts)), dtype=wp.int32),
            )

    def __call__(self, pairs, moved):
        counts = [len(points) for points in moved]
        with wp.ScopedDevice(self.device):
            found = wp.empty(sum(counts), dtype=wp.int32)
            wp.launch(
                registration.find_nearest_points,
                dim=sum(counts),
                inputs=[
                    self.grid.id,
                    self.points,
                    wp.array(np.concatenate(moved), dtype=wp.vec3d),
                    wp.array(np.repeat(np.asarray(pairs, np.int32), counts), dtype=wp.int32),
                    wp.float64(self.max_distance_m),
                ],
                outputs=[found],
            )
            index = found.numpy()
        # back to each target's own numbering
        return [
            np.where(part >= 0, part - self.starts[pair], -1)
            for pair, part in zip(pairs, np.split(index, np.cumsum(counts)[:-1]))
        ]


def _xyh_steps(moved: np.ndarray, matched: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Best 2D rigid motions (x, y, yaw) of `moved` onto `matched` (P,N,3), weighted."""
    total = np.maximum(weight.sum(axis=1), 1)[:, None]
    a, b = moved[..., :2], matched[..., :2]
    ca = np.einsum("pn,pni->pi", weight, a) / total
    cb = np.einsum("pn,pni->pi", weight, b) / total
    cross = np.einsum("pn,pni,pnj->pij", weight, a - ca[:, None], b - cb[:, None])
    u, _, vt = np.linalg.svd(cross)
    flip = np.linalg.det(u @ vt) < 0
    vt[flip, -1] *= -1
    rotation = np.transpose(u @ vt, (0, 2, 1))
    steps = np.tile(np.eye(4), (len(moved), 1, 1))
    steps[:, :2, :2] = rotation
    steps[:, :2, 3] = cb - np.einsum("pij,pj->pi", rotation, ca)
    return steps


def _result(source, target, tree, normals, T, converged, iterations, config, method, centre) -> IcpResult:
    moved = source @ T[:3, :3].T + T[:3, 3]
    # one thread, as in target_normals: threads cost these clouds more than they save
    distance, index = tree.query(moved, distance_upper_bound=config.max_correspondence_m)
    inlier = np.isfinite(distance)
    if inlier.any():
        local = source[inlier] - centre if centre.any() else source[inlier]
        J, _ = _plane_system(moved[inlier], T[:3, :3], local, target[index[inlier]], normals[index[inlier]])
        J = J * _free_columns(config, method)
        H_centre = J.T @ J
        fitness = float(np.mean(distance[inlier] ** 2))
    else:
        H_centre, fitness = np.zeros((6, 6)), float("inf")
    values, vectors = np.linalg.eigh(H_centre)
    num_inliers = int(inlier.sum())
    good = values >= config.lambda_min * max(num_inliers, 1)
    # J_centre = J_origin A, so H_origin = A^-T H_centre A^-1
    A_inv = np.linalg.inv(centre_adjoint(centre))
    H = A_inv.T @ H_centre @ A_inv if centre.any() else H_centre
    result = IcpResult(
        T,
        bool(converged and num_inliers >= config.min_inliers),
        fitness,
        num_inliers,
        iterations,
        H,
        values,
        vectors,
        vectors[:, good],
        centre,
    )
    return dataclasses.replace(result, basis=constrained_basis(result, good))


def _free_columns(config: IcpConfig, method: str = "point_to_plane") -> np.ndarray:
    """Mask of the tangent directions (rotation, translation) ICP may move: a held direction
    contributes nothing to J^T J, so it is never updated and never reported as constrained.
    "yaw" frees the rotation about the source's z axis (the vehicle's vertical when it is about
    level; through the cloud's centre, in the tangent there, which with the translation
    reaches the same motions) with the translation; the 2D point-to-point method moves x, y and yaw only."""
    if method == "point_to_point_xyh":
        return np.array([0.0, 0.0, 1.0, 1.0, 1.0, 0.0])
    rotation = [config.free == "all"] * 2 + [config.free in ("all", "yaw")]
    return np.array(rotation + [True] * 3, dtype=np.float64)


def _cloud(name: str, value) -> np.ndarray:
    cloud = real_array(name, value)
    if cloud.ndim != 2 or cloud.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {cloud.shape}")
    if len(cloud) < MIN_POINTS:
        raise ValueError(f"{name} needs at least {MIN_POINTS} points, got {len(cloud)}")
    if not np.all(np.isfinite(cloud)):
        raise ValueError(f"{name} contains NaN or infinite values")
    if np.abs(cloud).max() > MAX_COORDINATE_M:
        raise ValueError(f"{name} has coordinates beyond {MAX_COORDINATE_M:g} m (the normals' squares would overflow)")
    return cloud
