"""Where submaps end: a fixed number of scans, or Sodhi et al.'s Eq. 2 covariance bound."""

from __future__ import annotations

from vogjax.config import PipelineConfig


class SubmapCutter:
    def __init__(self, config: PipelineConfig):
        self.scans_per_submap = config.scans_per_submap
        noise = config.nav_noise
        # Eq. 2: the variances grow linearly in time, so the bound is a longest duration.
        self.max_duration_s = min(
            config.max_xy_variance_m2 / max(noise.sigma2_x, noise.sigma2_y),
            config.max_yaw_variance_rad2 / noise.sigma2_yaw,
        )

    def ends_before(self, scans_in_submap: int, elapsed_s: float) -> bool:
        """Should a submap that holds `scans_in_submap` scans over `elapsed_s` end before the next?"""
        if self.scans_per_submap is not None:
            return scans_in_submap >= self.scans_per_submap
        return elapsed_s > self.max_duration_s * (1 + 1e-9)  # round-off in time stamps is not drift

    def room(self, scans_in_submap: int, elapsed_s) -> int:
        """How many of the next scans (elapsed_s (n,) since the base pose) still fit the submap."""
        for n, elapsed in enumerate(elapsed_s):
            if self.ends_before(scans_in_submap + n, float(elapsed)):
                return n
        return len(elapsed_s)
