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

from vogjax.geometry import euler_rates, wrap_angle, yaw_pitch_roll


def _heading_frame(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, s, 0.0], [-s, c, 0.0]])  # rows of Rz(yaw)^T that give x, y


def xyh(T_a: np.ndarray, T_b: np.ndarray) -> np.ndarray:
    """(3,) x, y of b in a's heading frame and yaw_b - yaw_a (wrapped)."""
    yaw_a = yaw_pitch_roll(T_a[:3, :3])[0]
    yaw_b = yaw_pitch_roll(T_b[:3, :3])[0]
    xy = _heading_frame(yaw_a) @ (T_b[:3, 3] - T_a[:3, 3])
    return np.array([xy[0], xy[1], wrap_angle(yaw_b - yaw_a)])


def xyh_jacobians(T_a: np.ndarray, T_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3,6), (3,6): d xyh / d xi_a and d xyh / d xi_b."""
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


def zpr(T: np.ndarray) -> np.ndarray:
    """(3,) z, pitch, roll."""
    _, pitch, roll = yaw_pitch_roll(T[:3, :3])
    return np.array([T[2, 3], pitch, roll])


def zpr_jacobian(T: np.ndarray) -> np.ndarray:
    """(3,6) d zpr / d xi."""
    J = np.zeros((3, 6))
    rates = euler_rates(T[:3, :3])
    J[0, 3:] = T[2, :3]
    J[1, :3] = rates[1]
    J[2, :3] = rates[2]
    return J
