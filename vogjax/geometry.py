"""All rotation and pose arithmetic of vogjax.

SE(3) on 4x4 homogeneous matrices, SO(3), z-y-x Euler angles (R = Rz(yaw) Ry(pitch) Rx(roll))
and quaternions (w, x, y, z). NumPy, float64, batched over leading axes; SciPy's Rotation where
it is the plain conversion. Twists are (rotation vector, translation part), GTSAM's tangent
order.

Pose names follow the frames: ``T_world_submap`` maps submap coordinates to world coordinates.
Angles are radians, lengths metres.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation, Slerp

from vogjax.validation import real_array

RIGID_TOLERANCE = 1e-6


def rigid_poses(name: str, value: npt.ArrayLike, count: int | None = None) -> npt.NDArray[np.float64]:
    """Check and convert a batch of rigid transforms.

    Rotation blocks must be orthonormal with determinant +1 (to RIGID_TOLERANCE, 1e-6) and the
    last row exactly 0 0 0 1.

    Parameters
    ----------
    name : str
        The argument's name, for error messages.
    value : (n, 4, 4) array_like of float
        The transforms; a single (4, 4) is accepted when `count` is None.
    count : int or None, optional
        The number of transforms required (None: any).

    Returns
    -------
    (n, 4, 4) ndarray of float64
        The transforms (n = 1 for a single one).

    Raises
    ------
    ValueError
        Naming `name`: not real numbers, the wrong shape (or count), NaN or infinite entries, a
        rotation part that is not a proper rotation, or a last row other than 0 0 0 1.
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
    if np.abs(rotations).max(initial=0.0) > 1.0 + RIGID_TOLERANCE:  # no rotation's entry is; and no overflow below
        return False
    gram_error = np.abs(rotations @ rotations.transpose(0, 2, 1) - np.eye(3)).max(initial=0.0)
    return not (gram_error > RIGID_TOLERANCE or np.any(np.linalg.det(rotations) < 0))


def _rigid_batch(name: str, value) -> np.ndarray:
    """Rigid transforms (..., 4, 4) as float64, checked as `rigid_poses` checks."""
    poses = real_array(name, value)
    if poses.ndim < 2 or poses.shape[-2:] != (4, 4):
        raise ValueError(f"{name} must have shape (..., 4, 4), got {poses.shape}")
    rigid_poses(name, poses.reshape(-1, 4, 4))
    return poses


def rigid_pose(name: str, value: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Check and convert one rigid transform, as `rigid_poses` checks.

    Parameters
    ----------
    name : str
        The argument's name, for error messages.
    value : (4, 4) array_like of float
        The transform.

    Returns
    -------
    (4, 4) ndarray of float64
        The transform.

    Raises
    ------
    ValueError
        Naming `name`: not a (4, 4) array of real numbers, or not rigid (see `rigid_poses`).
    """
    array = real_array(name, value)
    if array.shape != (4, 4):
        raise ValueError(f"{name} must have shape (4, 4), got {array.shape}")
    return rigid_poses(name, array)[0]


def inverse(poses: npt.NDArray[np.floating]) -> npt.NDArray[np.floating]:
    """Inverse of rigid transforms, from the transpose of their rotations (not checked).

    Parameters
    ----------
    poses : (..., 4, 4) ndarray of float
        Rigid transforms ``T_a_b``.

    Returns
    -------
    (..., 4, 4) ndarray
        ``T_b_a``, of the dtype of `poses`.
    """
    out = np.zeros_like(poses)
    rotation_t = np.swapaxes(poses[..., :3, :3], -1, -2)
    out[..., :3, :3] = rotation_t
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rotation_t, poses[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


NEAR_HALF_TURN = 1e-6  # 1 + cos below which log_so3 reads the axis off R's symmetric part


def log_so3(rotations: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
    """SO(3) logarithm: the rotation vectors of rotation matrices.

    Stable near the identity and near a half turn (where the axis comes from R's symmetric
    part: within about 1.4e-3 rad of pi, R - R^T holds little but round-off).

    Parameters
    ----------
    rotations : (..., 3, 3) ndarray of float
        Proper rotation matrices (not checked).

    Returns
    -------
    (..., 3) ndarray of float64
        Rotation vectors: axis times angle, the angle in [0, pi] radians.
    """
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
    # Within about 1.4e-3 rad of a half turn, R - R^T is round-off over sin ~ 1e-8 (arccos
    # resolves cos near -1 only to ~1.5e-8 rad): the axis comes from the symmetric part instead,
    # (R + R^T) / 2 - cos I = (1 - cos) a a^T, its sign from R - R^T, and the angle from atan2.
    near_pi = cos < -1.0 + NEAR_HALF_TURN
    if np.any(near_pi):
        R, c, w = rotations[near_pi], cos[near_pi], skew[near_pi]
        outer = ((R + np.swapaxes(R, -1, -2)) / 2.0 - c[:, None, None] * np.eye(3)) / (1.0 - c)[:, None, None]
        column = np.argmax(np.diagonal(outer, axis1=-2, axis2=-1), axis=-1)
        axis = outer[np.arange(len(outer)), :, column]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        axis *= np.where(np.einsum("ij,ij->i", axis, w) < 0.0, -1.0, 1.0)[:, None]
        theta = np.arctan2(np.linalg.norm(w, axis=-1) / 2.0, c)
        vector[near_pi] = axis * theta[:, None]
    return vector


def skew(vectors: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Cross-product matrices: ``skew(v) @ u == cross(v, u)``.

    Parameters
    ----------
    vectors : (..., 3) array_like of float
        The vectors.

    Returns
    -------
    (..., 3, 3) ndarray of float64
        Their skew-symmetric matrices.
    """
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


def exp_se3(twists: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """SE(3) exponential of twists.

    Parameters
    ----------
    twists : (..., 6) array_like of float
        (rotation vector omega in radians, translation part v in metres).

    Returns
    -------
    (..., 4, 4) ndarray of float64
        The rigid transforms ``exp(twist)``.
    """
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


def log_se3(poses: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
    """SE(3) logarithm, the inverse of `exp_se3`.

    Parameters
    ----------
    poses : (..., 4, 4) ndarray of float
        Rigid transforms (not checked).

    Returns
    -------
    (..., 6) ndarray of float64
        Twists (rotation vector, translation part rho) with ``exp_se3(twist) == pose``; a series
        below 1e-4 rad keeps small rotations accurate.
    """
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


def pose_deltas(T_old: npt.ArrayLike, T_new: npt.ArrayLike) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """How far each pose moved: the rotation angle and translation norm of ``log(T_old^-1 T_new)``.

    These are the quantities Algorithm 1 compares with eps_rot and eps_trans.

    Parameters
    ----------
    T_old : (..., 4, 4) array_like of float
        The poses before, rigid (checked as `rigid_poses` checks: the SE(3) log of anything else
        is meaningless, and a scaled pose would read as no motion).
    T_new : (..., 4, 4) array_like of float
        The poses after, of the same shape, rigid.

    Returns
    -------
    angle : (...) ndarray of float64
        Rotation angle of each relative pose, radians.
    translation : (...) ndarray of float64
        Norm of the translation part of its twist, metres.

    Raises
    ------
    ValueError
        Naming `T_old` or `T_new` if it is not a batch of rigid transforms.
    """
    T_old, T_new = _rigid_batch("T_old", T_old), _rigid_batch("T_new", T_new)
    twist = log_se3(inverse(T_old) @ T_new)
    return np.linalg.norm(twist[..., :3], axis=-1), np.linalg.norm(twist[..., 3:], axis=-1)


def xyh_covariance(marginals: npt.NDArray[np.floating]) -> npt.NDArray[np.floating]:
    """The x, y, yaw block of GTSAM Pose3 marginal covariances.

    Parameters
    ----------
    marginals : (..., 6, 6) ndarray of float
        Covariances in GTSAM's tangent order (rotation x, y, z, then translation x, y, z).

    Returns
    -------
    (..., 3, 3) ndarray
        Covariance of (x, y, yaw): m^2, m rad, rad^2.
    """
    index = [3, 4, 2]
    return marginals[..., index, :][..., :, index]


# 95% quantile of the chi-square distribution with 3 degrees of freedom.
CHI2_3DOF_95 = 7.814727903251178


# Relative to each matrix's largest entry, as GlobalMap checks marginals (at 1e-11): a
# principal block's eigenvalues lie within the full matrix's, so whatever it accepts passes
# here, with room for round-off; singular (PSD) covariances give volume 0.
_PSD_TOLERANCE = 1e-10


def confidence_volume(marginals: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Volume of the 95% confidence ellipsoid of x, y, yaw of each marginal covariance.

    Algorithm 1's measure of a submap's uncertainty (compared with eps_cov):
    ``4/3 pi chi2_3(0.95)^1.5 sqrt(det Sigma_xyh)``.

    Parameters
    ----------
    marginals : (..., 6, 6) array_like of float
        GTSAM Pose3 marginal covariances (rotation, then translation): finite, and symmetric and
        positive semi-definite in x, y, yaw up to round-off (1e-10 of each matrix's largest
        entry).

    Returns
    -------
    (...) ndarray of float64
        The volumes, m^2 rad; 0 for a singular covariance.

    Raises
    ------
    ValueError
        If `marginals` has the wrong shape, holds NaN or infinite values, or is not symmetric or
        not positive semi-definite in x, y, yaw.
    """
    marginals = real_array("marginals", marginals)
    if marginals.ndim < 2 or marginals.shape[-2:] != (6, 6):
        raise ValueError(f"marginals must have shape (..., 6, 6), got {marginals.shape}")
    if not np.all(np.isfinite(marginals)):
        raise ValueError("marginals contains NaN or infinite values")
    block = xyh_covariance(marginals)
    scale = np.abs(marginals).max(axis=(-2, -1), initial=0.0)  # each matrix its own
    if np.any(np.abs(block - np.swapaxes(block, -1, -2)).max(axis=(-2, -1), initial=0.0) > _PSD_TOLERANCE * scale):
        raise ValueError("marginals must be symmetric in x, y, yaw")
    if block.size and np.any(np.linalg.eigvalsh(block).min(axis=-1) < -_PSD_TOLERANCE * scale):
        raise ValueError("marginals must be positive semi-definite in x, y, yaw (a covariance)")
    det = np.clip(np.linalg.det(block), 0.0, None)
    return 4.0 / 3.0 * np.pi * CHI2_3DOF_95**1.5 * np.sqrt(det)


def wrap_angle(angle: Any) -> Any:
    """Angles wrapped to [-pi, pi).

    Parameters
    ----------
    angle : float or array_like
        Angles, radians: a float, a NumPy or a JAX array.

    Returns
    -------
    float or array
        The wrapped angles, of the type of `angle` (a JAX array stays one, for jitted code).
    """
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def yaw_pitch_roll(rotations: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """z-y-x Euler angles of rotation matrices (R = Rz(yaw) Ry(pitch) Rx(roll)).

    Parameters
    ----------
    rotations : (..., 3, 3) array_like of float
        Rotation matrices.

    Returns
    -------
    (..., 3) ndarray of float64
        (yaw, pitch, roll), radians; pitch in [-pi/2, pi/2].
    """
    r = np.asarray(rotations, dtype=np.float64)
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    pitch = np.arcsin(np.clip(-r[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    return np.stack([yaw, pitch, roll], axis=-1)


def rotation_from_ypr(
    yaw: npt.ArrayLike, pitch: npt.ArrayLike = 0.0, roll: npt.ArrayLike = 0.0
) -> npt.NDArray[np.float64]:
    """Rotation matrices Rz(yaw) Ry(pitch) Rx(roll).

    Parameters
    ----------
    yaw : float or (...) array_like of float
        Rotation about z, radians.
    pitch : float or (...) array_like of float, optional
        Rotation about the new y, radians; broadcast against `yaw`.
    roll : float or (...) array_like of float, optional
        Rotation about the new x, radians; broadcast against `yaw`.

    Returns
    -------
    (..., 3, 3) ndarray of float64
        One rotation per broadcast element; (3, 3) for scalars.
    """
    angles = np.stack(np.broadcast_arrays(yaw, pitch, roll), axis=-1).astype(np.float64)
    return Rotation.from_euler("ZYX", angles.reshape(-1, 3)).as_matrix().reshape(*angles.shape[:-1], 3, 3)


def euler_rates(rotation: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Jacobian of the z-y-x Euler angles under a body-frame rotation perturbation ``R Exp(omega)``.

    Parameters
    ----------
    rotation : (3, 3) array_like of float
        The rotation R (singular at pitch = +-pi/2).

    Returns
    -------
    (3, 3) ndarray of float64
        ``d(yaw, pitch, roll) / d(omega)``.
    """
    _, pitch, roll = yaw_pitch_roll(rotation)
    sr, cr = np.sin(roll), np.cos(roll)
    cp, tp = np.cos(pitch), np.tan(pitch)
    return np.array([[0.0, sr / cp, cr / cp], [0.0, cr, -sr], [1.0, sr * tp, cr * tp]])


def align_xy_yaw(positions: npt.ArrayLike, reference: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """The rotation about z and x-y translation taking `positions` closest to `reference`.

    These are the directions a pose graph with absolute depth, pitch and roll cannot observe:
    its whole solution inherits them from where the first pose was anchored. The yaw has a
    closed form (the angle of the summed cross and dot products of the centred x-y points).

    Parameters
    ----------
    positions : (N, 3) array_like of float
        Points to move, metres.
    reference : (N, 3) array_like of float
        Where they should be, point by point, metres.

    Returns
    -------
    (4, 4) ndarray of float64
        The transform minimising the x-y least-squares error; it leaves z as it is.
    """
    a = np.asarray(positions, dtype=np.float64)[:, :2]
    b = np.asarray(reference, dtype=np.float64)[:, :2]
    a_mean, b_mean = a.mean(axis=0), b.mean(axis=0)
    a_c, b_c = a - a_mean, b - b_mean
    yaw = np.arctan2(np.sum(a_c[:, 0] * b_c[:, 1] - a_c[:, 1] * b_c[:, 0]), np.sum(a_c * b_c))
    T = pose_from_xyz_yaw(0.0, 0.0, 0.0, yaw)
    T[:2, 3] = b_mean - T[:2, :2] @ a_mean
    return T


def pose_from_xyz_yaw(x: float, y: float, z: float, yaw: float) -> npt.NDArray[np.float64]:
    """The pose of a level body at a position and heading.

    Parameters
    ----------
    x, y, z : float
        Position, metres.
    yaw : float
        Heading, radians (rotation about z; pitch and roll 0).

    Returns
    -------
    (4, 4) ndarray of float64
        ``T_world_body``.
    """
    T = np.eye(4)
    T[:3, :3] = rotation_from_ypr(yaw)
    T[:3, 3] = [x, y, z]
    return T


def rotation_from_quaternion(q: Any, xp: ModuleType = np) -> Any:
    """Rotation matrix of a unit quaternion, in NumPy or jax.numpy.

    Parameters
    ----------
    q : (4,) array_like of float
        Unit quaternion (w, x, y, z) (not normalised here).
    xp : module, optional
        The array module: NumPy, or jax.numpy so the simulator's jitted controller shares it.

    Returns
    -------
    (3, 3) array
        The rotation, an array of `xp`.
    """
    w, x, y, z = q[0], q[1], q[2], q[3]
    return xp.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def yaw_of_quaternion(q: Any, xp: ModuleType = np) -> Any:
    """Yaw (z-y-x Euler) of a unit quaternion, in NumPy or jax.numpy.

    Parameters
    ----------
    q : (4,) array_like of float
        Unit quaternion (w, x, y, z).
    xp : module, optional
        The array module, as in `rotation_from_quaternion`.

    Returns
    -------
    scalar array
        The yaw in [-pi, pi] radians, an array of `xp`.
    """
    w, x, y, z = q[0], q[1], q[2], q[3]
    return xp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def quaternions_from_rotations(rotations: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Unit quaternions of rotation matrices.

    Parameters
    ----------
    rotations : (..., 3, 3) array_like of float
        Proper rotations, orthonormal to RIGID_TOLERANCE (1e-6) with determinant +1: checked,
        since SciPy would quietly take the nearest rotation.

    Returns
    -------
    (..., 4) ndarray of float64
        Unit quaternions (w, x, y, z).

    Raises
    ------
    ValueError
        If `rotations` has the wrong shape, holds NaN or infinite values or is not a proper
        rotation.
    """
    r = real_array("rotations", rotations)
    if r.ndim < 2 or r.shape[-2:] != (3, 3):
        raise ValueError(f"rotations must have shape (..., 3, 3), got {r.shape}")
    if not np.all(np.isfinite(r)):
        raise ValueError("rotations contains NaN or infinite values")
    if not _proper_rotations(r.reshape(-1, 3, 3)):
        raise ValueError(f"rotations must be proper rotations (orthonormal to {RIGID_TOLERANCE:g}, determinant +1)")
    q = Rotation.from_matrix(r.reshape(-1, 3, 3)).as_quat(scalar_first=True)
    return q.reshape(*r.shape[:-2], 4)


def rotations_from_quaternions(quaternions: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Rotation matrices of quaternions, normalised first.

    Parameters
    ----------
    quaternions : (..., 4) array_like of float
        Quaternions (w, x, y, z): finite, of non-zero norm.

    Returns
    -------
    (..., 3, 3) ndarray of float64
        The rotations.

    Raises
    ------
    ValueError
        If `quaternions` has the wrong shape, holds NaN or infinite values or one of zero norm.
    """
    q = real_array("quaternions", quaternions)
    if q.ndim < 1 or q.shape[-1] != 4:
        raise ValueError(f"quaternions must have shape (..., 4), got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise ValueError("quaternions contains NaN or infinite values")
    if q.size and not np.all(np.linalg.norm(q, axis=-1) > 0):
        raise ValueError("quaternions must have non-zero norm")
    return Rotation.from_quat(q.reshape(-1, 4), scalar_first=True).as_matrix().reshape(*q.shape[:-1], 3, 3)


def interpolate_poses(
    times: npt.ArrayLike, poses: npt.NDArray[np.floating], query_times: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """Poses interpolated at query times: positions linearly, rotations by slerp.

    Parameters
    ----------
    times : (N,) array_like of float
        Strictly increasing times of the poses, seconds (not checked).
    poses : (N, 4, 4) ndarray of float
        Rigid poses at `times`.
    query_times : (M,) array_like of float
        Times within ``[times[0], times[-1]]`` (a single pose answers every query with itself).

    Returns
    -------
    (M, 4, 4) ndarray of float64
        The interpolated poses.
    """
    t = np.asarray(times, dtype=np.float64)
    q = np.asarray(query_times, dtype=np.float64)
    if len(t) == 1:
        return np.repeat(poses, len(q), axis=0)
    out = np.tile(np.eye(4), (len(q), 1, 1))
    out[:, :3, :3] = Slerp(t, Rotation.from_matrix(poses[:, :3, :3]))(q).as_matrix()
    for axis in range(3):
        out[:, axis, 3] = np.interp(q, t, poses[:, axis, 3])
    return out
