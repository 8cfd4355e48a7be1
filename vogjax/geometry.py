"""All rotation and pose arithmetic of vogjax: SE(3) on 4x4 homogeneous matrices, SO(3),
z-y-x Euler angles (R = Rz(yaw) Ry(pitch) Rx(roll)) and quaternions (w, x, y, z). NumPy,
float64, batched over leading axes; SciPy's Rotation where it is the plain conversion.

Pose names follow the frames: T_world_submap maps submap coordinates to world coordinates."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from vogjax.validation import real_array

RIGID_TOLERANCE = 1e-6


def rigid_poses(name: str, value, count: int | None = None) -> np.ndarray:
    """(n,4,4) float64 rigid transforms (a single (4,4) is accepted when count is None).

    Rotation blocks must be orthonormal with determinant +1 (to 1e-6) and the last row 0 0 0 1.
    """
    poses = real_array(name, value)
    single = poses.ndim == 2
    if single and count is None:
        poses = poses[None]
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or (count is not None and poses.shape[0] != count):
        wanted = "(4, 4)" if count is None else f"({count}, 4, 4)"
        raise ValueError(f"{name} must have shape {wanted}, got {np.shape(value)}")
    if not np.all(np.isfinite(poses)):
        raise ValueError(f"{name} contains NaN or infinite values")
    if not _proper_rotations(poses[:, :3, :3]):
        raise ValueError(f"{name} is not rigid: its rotation part is not a proper rotation")
    if np.abs(poses[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(initial=0.0) > 0:
        raise ValueError(f"{name} is not rigid: its last row must be 0 0 0 1")
    return poses


def _proper_rotations(rotations: np.ndarray) -> bool:
    """Whether finite (n,3,3) matrices are orthonormal to RIGID_TOLERANCE with determinant +1."""
    gram_error = np.abs(rotations @ rotations.transpose(0, 2, 1) - np.eye(3)).max(initial=0.0)
    return not (gram_error > RIGID_TOLERANCE or np.any(np.linalg.det(rotations) < 0))


def _rigid_batch(name: str, value) -> np.ndarray:
    """Rigid transforms (..., 4, 4) as float64, checked as `rigid_poses` checks."""
    poses = real_array(name, value)
    if poses.ndim < 2 or poses.shape[-2:] != (4, 4):
        raise ValueError(f"{name} must have shape (..., 4, 4), got {poses.shape}")
    rigid_poses(name, poses.reshape(-1, 4, 4))
    return poses


def rigid_pose(name: str, value) -> np.ndarray:
    """One (4,4) float64 rigid transform, checked as `rigid_poses` checks."""
    array = real_array(name, value)
    if array.shape != (4, 4):
        raise ValueError(f"{name} must have shape (4, 4), got {array.shape}")
    return rigid_poses(name, array)[0]


def inverse(poses: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4)."""
    out = np.zeros_like(poses)
    rotation_t = np.swapaxes(poses[..., :3, :3], -1, -2)
    out[..., :3, :3] = rotation_t
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rotation_t, poses[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def log_so3(rotations: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) of rotation matrices (..., 3, 3)."""
    cos = np.clip((np.trace(rotations, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    skew = np.stack(
        [
            rotations[..., 2, 1] - rotations[..., 1, 2],
            rotations[..., 0, 2] - rotations[..., 2, 0],
            rotations[..., 1, 0] - rotations[..., 0, 1],
        ],
        axis=-1,
    )
    sin = np.sin(angle)
    small = sin < 1e-9
    scale = np.where(small, 0.5, angle / (2.0 * np.where(small, 1.0, sin)))
    vector = skew * scale[..., None]
    near_pi = small & (angle > 1.0)
    if np.any(near_pi):  # angle ~ pi: the axis is the dominant column of (R + I) / 2
        b = (rotations[near_pi] + np.eye(3)) / 2.0
        column = np.argmax(np.diagonal(b, axis1=-2, axis2=-1), axis=-1)
        axis = b[np.arange(len(b)), :, column]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        vector[near_pi] = axis * angle[near_pi, None]
    return vector


def skew(vectors: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cross-product matrices of vectors (..., 3)."""
    v = np.asarray(vectors, dtype=np.float64)
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        axis=-2,
    )


def exp_se3(twists: np.ndarray) -> np.ndarray:
    """SE(3) exponential of twists (..., 6) = (rotation vector omega, v) -> (..., 4, 4)."""
    xi = np.asarray(twists, dtype=np.float64)
    omega, v = xi[..., :3], xi[..., 3:]
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    W = skew(omega)
    WW = W @ W
    small = theta < 1e-10
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(t) / t)
    b = np.where(small, 0.5, (1 - np.cos(t)) / t**2)
    c = np.where(small, 1.0 / 6.0, (t - np.sin(t)) / t**3)
    eye = np.eye(3)
    T = np.zeros((*xi.shape[:-1], 4, 4))
    T[..., :3, :3] = eye + a * W + b * WW
    T[..., :3, 3] = np.einsum("...ij,...j->...i", eye + b * W + c * WW, v)
    T[..., 3, 3] = 1.0
    return T


def log_se3(poses: np.ndarray) -> np.ndarray:
    """Twists (..., 6) = (rotation vector, translation part rho) with exp(twist) = pose."""
    omega = log_so3(poses[..., :3, :3])
    theta = np.linalg.norm(omega, axis=-1)
    t = poses[..., :3, 3]
    # below 1e-4 rad the closed form loses every digit to cancellation (1 - cos rounds to 0)
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    # V^-1 = I - W/2 + (1/theta^2)(1 - theta sin / (2 (1 - cos))) W^2
    coefficient = np.where(
        small, 1.0 / 12.0 + theta**2 / 720.0, (1.0 - safe * np.sin(safe) / (2.0 * (1.0 - np.cos(safe)))) / safe**2
    )
    w_t = np.cross(omega, t)
    w_w_t = np.cross(omega, w_t)
    rho = t - 0.5 * w_t + coefficient[..., None] * w_w_t
    return np.concatenate([omega, rho], axis=-1)


def pose_deltas(T_old: np.ndarray, T_new: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation angle (rad) and translation norm (m) of log(T_old^-1 T_new), per pose, for rigid
    poses (..., 4, 4) (checked as `rigid_poses` checks: the SE(3) log of anything else is
    meaningless, and a scaled pose would read as no motion)."""
    T_old, T_new = _rigid_batch("T_old", T_old), _rigid_batch("T_new", T_new)
    twist = log_se3(inverse(T_old) @ T_new)
    return np.linalg.norm(twist[..., :3], axis=-1), np.linalg.norm(twist[..., 3:], axis=-1)


def xyh_covariance(marginals: np.ndarray) -> np.ndarray:
    """(..., 3, 3) covariance of x, y, yaw from GTSAM Pose3 marginals (rotation, translation)."""
    index = [3, 4, 2]
    return marginals[..., index, :][..., :, index]


# 95% quantile of the chi-square distribution with 3 degrees of freedom.
CHI2_3DOF_95 = 7.814727903251178


# Relative to the largest entry of the batch (at least 1), as GlobalMap checks marginals (at
# 1e-9): a principal block's eigenvalues lie within the full matrix's, so whatever it accepts
# passes here, with room for round-off; singular (PSD) covariances give volume 0.
_PSD_TOLERANCE = 1e-8


def confidence_volume(marginals: np.ndarray) -> np.ndarray:
    """Volume of the 95% confidence ellipsoid of x, y, yaw for each (6,6) marginal covariance
    (..., 6, 6): finite, and positive semi-definite in x, y, yaw up to round-off."""
    marginals = real_array("marginals", marginals)
    if marginals.ndim < 2 or marginals.shape[-2:] != (6, 6):
        raise ValueError(f"marginals must have shape (..., 6, 6), got {marginals.shape}")
    if not np.all(np.isfinite(marginals)):
        raise ValueError("marginals contains NaN or infinite values")
    block = xyh_covariance(marginals)
    scale = np.abs(marginals).max(initial=1.0)
    if np.abs(block - np.swapaxes(block, -1, -2)).max(initial=0.0) > _PSD_TOLERANCE * scale:
        raise ValueError("marginals must be symmetric in x, y, yaw")
    if block.size and np.linalg.eigvalsh(block).min() < -_PSD_TOLERANCE * scale:
        raise ValueError("marginals must be positive semi-definite in x, y, yaw (a covariance)")
    det = np.clip(np.linalg.det(block), 0.0, None)
    return 4.0 / 3.0 * np.pi * CHI2_3DOF_95**1.5 * np.sqrt(det)


def wrap_angle(angle):
    """Angles wrapped to [-pi, pi) (NumPy or JAX arrays, or floats)."""
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def yaw_pitch_roll(rotations: np.ndarray) -> np.ndarray:
    """(..., 3) z-y-x Euler angles of rotation matrices (..., 3, 3)."""
    r = np.asarray(rotations, dtype=np.float64)
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    pitch = np.arcsin(np.clip(-r[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    return np.stack([yaw, pitch, roll], axis=-1)


def rotation_from_ypr(yaw, pitch=0.0, roll=0.0) -> np.ndarray:
    """(..., 3, 3) rotation matrices Rz(yaw) Ry(pitch) Rx(roll)."""
    angles = np.stack(np.broadcast_arrays(yaw, pitch, roll), axis=-1).astype(np.float64)
    return Rotation.from_euler("ZYX", angles.reshape(-1, 3)).as_matrix().reshape(*angles.shape[:-1], 3, 3)


def euler_rates(rotation: np.ndarray) -> np.ndarray:
    """(3,3) d(yaw, pitch, roll) / d(omega) for a body-frame rotation perturbation R Exp(omega)."""
    _, pitch, roll = yaw_pitch_roll(rotation)
    sr, cr = np.sin(roll), np.cos(roll)
    cp, tp = np.cos(pitch), np.tan(pitch)
    return np.array([[0.0, sr / cp, cr / cp], [0.0, cr, -sr], [1.0, sr * tp, cr * tp]])


def align_xy_yaw(positions: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(4,4) rotation about z and x-y translation taking `positions` (N,3) closest to
    `reference` (N,3) in least squares; z is left as it is.

    These are the directions a pose graph with absolute depth, pitch and roll cannot observe:
    its whole solution inherits them from where the first pose was anchored. The yaw has a
    closed form (the angle of the summed cross and dot products of the centred x-y points)."""
    a = np.asarray(positions, dtype=np.float64)[:, :2]
    b = np.asarray(reference, dtype=np.float64)[:, :2]
    a_mean, b_mean = a.mean(axis=0), b.mean(axis=0)
    a_c, b_c = a - a_mean, b - b_mean
    yaw = np.arctan2(np.sum(a_c[:, 0] * b_c[:, 1] - a_c[:, 1] * b_c[:, 0]), np.sum(a_c * b_c))
    T = pose_from_xyz_yaw(0.0, 0.0, 0.0, yaw)
    T[:2, 3] = b_mean - T[:2, :2] @ a_mean
    return T


def pose_from_xyz_yaw(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    """(4,4) T_world_body of a level body at (x, y, z) heading `yaw`."""
    T = np.eye(4)
    T[:3, :3] = rotation_from_ypr(yaw)
    T[:3, 3] = [x, y, z]
    return T


def rotation_from_quaternion(q, xp=np):
    """(3,3) rotation of a unit quaternion (w, x, y, z); `xp`: the array module (NumPy or
    jax.numpy, so the simulator's jitted controller shares it)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return xp.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def yaw_of_quaternion(q, xp=np):
    """Yaw (z-y-x Euler) of a unit quaternion (w, x, y, z); `xp` as in rotation_from_quaternion."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return xp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def quaternions_from_rotations(rotations: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z) of rotation matrices (..., 3, 3), which must be
    proper rotations to RIGID_TOLERANCE (SciPy would quietly take the nearest one)."""
    r = real_array("rotations", rotations)
    if r.ndim < 2 or r.shape[-2:] != (3, 3):
        raise ValueError(f"rotations must have shape (..., 3, 3), got {r.shape}")
    if not np.all(np.isfinite(r)):
        raise ValueError("rotations contains NaN or infinite values")
    if not _proper_rotations(r.reshape(-1, 3, 3)):
        raise ValueError(f"rotations must be proper rotations (orthonormal to {RIGID_TOLERANCE:g}, determinant +1)")
    q = Rotation.from_matrix(r.reshape(-1, 3, 3)).as_quat(scalar_first=True)
    return q.reshape(*r.shape[:-2], 4)


def rotations_from_quaternions(quaternions: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices of quaternions (..., 4) (w, x, y, z), normalised first
    (finite, of non-zero norm)."""
    q = real_array("quaternions", quaternions)
    if q.ndim < 1 or q.shape[-1] != 4:
        raise ValueError(f"quaternions must have shape (..., 4), got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise ValueError("quaternions contains NaN or infinite values")
    if q.size and not np.all(np.linalg.norm(q, axis=-1) > 0):
        raise ValueError("quaternions must have non-zero norm")
    return Rotation.from_quat(q.reshape(-1, 4), scalar_first=True).as_matrix().reshape(*q.shape[:-1], 3, 3)


def interpolate_poses(times: np.ndarray, poses: np.ndarray, query_times: np.ndarray) -> np.ndarray:
    """Poses (N,4,4) at increasing times (N,), interpolated at query times (M,) within their
    span: positions linearly, rotations by slerp."""
    t = np.asarray(times, dtype=np.float64)
    q = np.asarray(query_times, dtype=np.float64)
    if len(t) == 1:
        return np.repeat(poses, len(q), axis=0)
    out = np.tile(np.eye(4), (len(q), 1, 1))
    out[:, :3, :3] = Slerp(t, Rotation.from_matrix(poses[:, :3, :3]))(q).as_matrix()
    for axis in range(3):
        out[:, axis, 3] = np.interp(q, t, poses[:, axis, 3])
    return out
