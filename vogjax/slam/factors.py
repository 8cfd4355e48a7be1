"""Measurement models of the pose graph with analytic Jacobians (NumPy; no GTSAM here).

Poses are 4x4 T_world_body. Jacobians are with respect to GTSAM's Pose3 tangent at the pose,
T * Exp(xi) with xi = (omega, v): body-frame rotation, then body-frame translation.

- xyh (relative, Sodhi et al. Eq. 3 f): x, y of the second pose in the heading-only frame of
  the first, and the yaw difference. What a DVL-and-compass navigation drifts in.
- zpr (unary, g): depth, pitch and roll, which a depth sensor and inclinometers give absolutely.
Euler angles are z-y-x: R = Rz(yaw) Ry(pitch) Rx(roll).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from vogjax.geometry import euler_rates, wrap_angle, yaw_pitch_roll


def _heading_frame(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, s, 0.0], [-s, c, 0.0]])  # rows of Rz(yaw)^T that give x, y


def xyh(T_a: npt.NDArray[np.floating], T_b: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
    """The relative x-y-yaw measurement of pose b from pose a (Sodhi et al. Eq. 3, f).

    Parameters
    ----------
    T_a, T_b : (4, 4) ndarray of float
        The two poses ``T_world_body``.

    Returns
    -------
    (3,) ndarray of float64
        x, y of b in a's heading frame (metres) and yaw_b - yaw_a wrapped to [-pi, pi) (rad).
    """
    yaw_a = yaw_pitch_roll(T_a[:3, :3])[0]
    yaw_b = yaw_pitch_roll(T_b[:3, :3])[0]
    xy = _heading_frame(yaw_a) @ (T_b[:3, 3] - T_a[:3, 3])
    return np.array([xy[0], xy[1], wrap_angle(yaw_b - yaw_a)])


def xyh_jacobians(
    T_a: npt.NDArray[np.floating], T_b: npt.NDArray[np.floating]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Jacobians of `xyh` with respect to both poses' GTSAM tangents.

    Parameters
    ----------
    T_a, T_b : (4, 4) ndarray of float
        The two poses ``T_world_body``.

    Returns
    -------
    J_a : (3, 6) ndarray of float64
        d xyh / d xi_a, xi = (omega, v) of T_a Exp(xi).
    J_b : (3, 6) ndarray of float64
        d xyh / d xi_b.
    """
    yaw_a = yaw_pitch_roll(T_a[:3, :3])[0]
    heading = _heading_frame(yaw_a)
    xy = heading @ (T_b[:3, 3] - T_a[:3, 3])
    dyaw_a = euler_rates(T_a[:3, :3])[0]
    dyaw_b = euler_rates(T_b[:3, :3])[0]
    J_a = np.zeros((3, 6))
    J_b = np.zeros((3, 6))
    J_a[:2, :3] = np.outer([xy[1], -xy[0]], dyaw_a)  # turning a turns its heading frame
    J_a[:2, 3:] = -heading @ T_a[:3, :3]
    J_a[2, :3] = -dyaw_a
    J_b[:2, 3:] = heading @ T_b[:3, :3]
    J_b[2, :3] = dyaw_b
    return J_a, J_b


def zpr(T: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
    """The unary depth-pitch-roll measurement of a pose (Sodhi et al. Eq. 3, g).

    Parameters
    ----------
    T : (4, 4) ndarray of float
        The pose ``T_world_body``.

    Returns
    -------
    (3,) ndarray of float64
        z (metres), pitch and roll (rad), of z-y-x Euler angles.
    """
    _, pitch, roll = yaw_pitch_roll(T[:3, :3])
    return np.array([T[2, 3], pitch, roll])


def zpr_jacobian(T: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
    """Jacobian of `zpr` with respect to the pose's GTSAM tangent.

    Parameters
    ----------
    T : (4, 4) ndarray of float
        The pose ``T_world_body``.

    Returns
    -------
    (3, 6) ndarray of float64
        d zpr / d xi, xi = (omega, v) of T Exp(xi).
    """
    J = np.zeros((3, 6))
    rates = euler_rates(T[:3, :3])
    J[0, 3:] = T[2, :3]
    J[1, :3] = rates[1]
    J[2, :3] = rates[2]
    return J
