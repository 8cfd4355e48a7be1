"""Drifting navigation a piece at a time, for closed-loop runs: chained pieces give the same
poses as `navigation.drifting_navigation` over the whole trajectory with the same seed."""

from __future__ import annotations

import numpy as np

from vogjax.config import NavNoise
from vogjax.geometry import inverse, rotation_from_ypr, yaw_pitch_roll


class SteppedNavigation:
    """Sodhi et al.'s Eq. 10 drift, extended as the vehicle flies (`extend`)."""

    def __init__(self, noise: NavNoise | None = None, seed: int = 0):
        self.noise = noise or NavNoise()
        self.rng = np.random.default_rng(seed)
        self.truth = None  # last true pose, time and navigation pose
        self.time_s = None
        self.nav = None

    def extend(self, truth: np.ndarray, times_s: np.ndarray) -> np.ndarray:
        """Navigation poses (S,4,4) for the next true poses (S,4,4) at times (S,). The first pose
        of the run is the truth itself; x, y and yaw noise then accumulate per step, while z,
        pitch and roll follow the truth plus noise (absolute sensors)."""
        nav = np.empty_like(truth)
        for t in range(len(truth)):
            if self.nav is None:
                nav[t] = truth[t]
            else:
                dt = float(times_s[t] - self.time_s)
                step = inverse(self.truth) @ truth[t]
                dx, dy, dyaw = self.rng.normal(0.0, np.sqrt(self.noise.xyh_variances(dt)))
                dz, dpitch, droll = self.rng.normal(0.0, np.sqrt(self.noise.zpr_variances(dt)))
                wobble = np.eye(4)
                wobble[:2, :2] = [[np.cos(dyaw), -np.sin(dyaw)], [np.sin(dyaw), np.cos(dyaw)]]
                wobble[:2, 3] = [dx, dy]
                pose = self.nav @ step @ wobble
                yaw = yaw_pitch_roll(pose[:3, :3])[0]
                _, pitch, roll = yaw_pitch_roll(truth[t, :3, :3])
                pose[:3, :3] = rotation_from_ypr(yaw, pitch + dpitch, roll + droll)
                pose[2, 3] = truth[t, 2, 3] + dz
                nav[t] = pose
            self.truth, self.time_s, self.nav = truth[t], float(times_s[t]), nav[t]
        return nav
