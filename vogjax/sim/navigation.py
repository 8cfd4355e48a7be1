"""Drifting navigation (Sodhi et al., Eq. 10): relative noise in x, y and yaw accumulates; z,
pitch and roll come from absolute sensors and carry independent noise."""

from __future__ import annotations

import numpy as np

from vogjax.config import NavNoise
from vogjax.config.schema import Rule
from vogjax.geometry import inverse, rigid_poses, rotation_from_ypr, yaw_pitch_roll
from vogjax.validation import real_array


def drifting_navigation(
    truth: np.ndarray, times_s: np.ndarray, noise: NavNoise | None = None, seed: int = 0
) -> np.ndarray:
    """Navigation poses drifting from the ground truth as in Sodhi et al. (Eq. 10), seeded.

    Each step's true motion is perturbed in x, y (its own frame) and yaw with variances
    sigma^2 * dt and chained onto the previous navigation pose; z, pitch and roll are then
    replaced by the truth's plus noise of variance sigma^2 * dt.

    Parameters
    ----------
    truth : (N, 4, 4) ndarray of float64
        Rigid ground-truth poses.
    times_s : (N,) ndarray of float64
        Their times: finite and non-decreasing (a step back in time would be a negative
        variance).
    noise : NavNoise or None, optional
        The variances per second (default: the papers').
    seed : int, optional
        Seed of the noise.

    Returns
    -------
    (N, 4, 4) ndarray of float64
        The navigation poses; the first is the truth's.

    Raises
    ------
    ValueError
        If the poses are not rigid, the times are not finite, of shape (N,) and
        non-decreasing, or `noise` is not a NavNoise.
    """
    truth = rigid_poses("truth", truth)
    times_s = real_array("times_s", times_s)
    if times_s.shape != (len(truth),):
        raise ValueError(f"times_s must have shape ({len(truth)},), one time per pose of truth, got {times_s.shape}")
    if not np.all(np.isfinite(times_s)):
        raise ValueError("times_s contains NaN or infinite values")
    if np.any(np.diff(times_s) < 0):
        raise ValueError("times_s must not decrease")
    noise = noise or NavNoise()
    if not isinstance(noise, NavNoise):
        raise ValueError(f"noise must be a NavNoise, got {type(noise).__name__}")
    Rule("integer", 0).check("seed", seed)
    rng = np.random.default_rng(seed)
    nav = np.empty_like(truth)
    if not len(truth):
        return nav
    nav[0] = truth[0]
    for t in range(1, len(truth)):
        dt = float(times_s[t] - times_s[t - 1])
        step = inverse(truth[t - 1]) @ truth[t]
        dx, dy, dyaw = rng.normal(0.0, np.sqrt(noise.xyh_variances(dt)))
        dz, dpitch, droll = rng.normal(0.0, np.sqrt(noise.zpr_variances(dt)))
        wobble = np.eye(4)
        wobble[:2, :2] = [[np.cos(dyaw), -np.sin(dyaw)], [np.sin(dyaw), np.cos(dyaw)]]
        wobble[:2, 3] = [dx, dy]
        pose = nav[t - 1] @ step @ wobble
        yaw = yaw_pitch_roll(pose[:3, :3])[0]
        _, pitch, roll = yaw_pitch_roll(truth[t, :3, :3])
        pose[:3, :3] = rotation_from_ypr(yaw, pitch + dpitch, roll + droll)
        pose[2, 3] = truth[t, 2, 3] + dz
        nav[t] = pose
    return nav
