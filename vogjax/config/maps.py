"""Settings of the occupancy maps."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from vogjax.config.schema import Config, number, positive, probability

# A beam crosses at most this many voxels: integration's scratch grows with it (4096 voxels at
# 0.1 m: 410 m, beyond any sonar or most lidars).
MAX_RANGE_VOXELS = 4096


def logodds(probability: float) -> np.float32:
    """Log-odds of a probability, rounded to float32 the way OctoMap stores it (+-inf at 1 and 0:
    clamping at those probabilities clamps nothing)."""
    if probability <= 0.0:
        return np.float32(-np.inf)
    if probability >= 1.0:
        return np.float32(np.inf)
    return np.float32(math.log(probability / (1.0 - probability)))


@dataclasses.dataclass(frozen=True)
class MapConfig(Config):
    """Occupancy map parameters. Defaults are those of Sodhi et al. (IV-C) with OctoMap's clamping.

    voxel_size:          edge of a voxel, metres; voxel k covers [k*s, (k+1)*s) on each axis
    prob_hit, prob_miss: inverse sensor model for the endpoint and the cells a beam crosses
    occupied_threshold:  probability at or above which a voxel is OCCUPIED
    free_threshold:      probability at or below which a voxel is FREE (between: UNKNOWN)
    clamp_min, clamp_max: probabilities the log-odds are clamped to after every update; 0 and 1
                         clamp nothing (Sodhi et al.'s p_min = 0, p_max = 1: `MapConfig.paper()`)
    max_range:           beams longer than this give free space up to it and no hit, metres
    """

    voxel_size: float = number(0.1, low=1e-4, high=1e3, doc="in m")
    prob_hit: float = probability(0.75)
    prob_miss: float = probability(0.2)
    occupied_threshold: float = probability(0.7)
    free_threshold: float = probability(0.3)
    clamp_min: float = number(0.1192, low=0, high=1, high_open=True)
    clamp_max: float = number(0.971, low=0, high=1, low_open=True)
    max_range: float = positive(11.0, doc="in m")

    @classmethod
    def paper(cls, **changes) -> MapConfig:
        """Sodhi et al. IV-C: 10 cm voxels, hit/miss 0.75/0.2, thresholds 0.7/0.3, and no clamping
        (p_min = 0, p_max = 1), which keeps every update invertible."""
        return cls(
            **{
                "voxel_size": 0.1,
                "prob_hit": 0.75,
                "prob_miss": 0.2,
                "occupied_threshold": 0.7,
                "free_threshold": 0.3,
                "clamp_min": 0.0,
                "clamp_max": 1.0,
                **changes,
            }
        )

    def check(self) -> None:
        if not self.prob_miss < 0.5 < self.prob_hit:
            raise ValueError("MapConfig.prob_hit must exceed 0.5 and MapConfig.prob_miss lie below it")
        if not self.free_threshold <= self.occupied_threshold:
            raise ValueError("MapConfig.free_threshold must not exceed MapConfig.occupied_threshold")
        if not self.clamp_min < self.clamp_max:
            raise ValueError("MapConfig.clamp_min must lie below MapConfig.clamp_max")
        if self.max_range > MAX_RANGE_VOXELS * self.voxel_size:
            raise ValueError(
                f"MapConfig.max_range must be at most {MAX_RANGE_VOXELS} voxels "
                f"({MAX_RANGE_VOXELS * self.voxel_size:g} m at voxel_size {self.voxel_size:g} m): "
                f"integration allocates per beam for every block a beam may cross, got {self.max_range!r}"
            )

    # Log-odds forms, float32 like the stored values.
    @property
    def log_hit(self) -> np.float32:
        return logodds(self.prob_hit)

    @property
    def log_miss(self) -> np.float32:
        return logodds(self.prob_miss)

    @property
    def log_occupied(self) -> np.float32:
        return logodds(self.occupied_threshold)

    @property
    def log_free(self) -> np.float32:
        return logodds(self.free_threshold)

    @property
    def log_clamp_min(self) -> np.float32:
        return logodds(self.clamp_min)

    @property
    def log_clamp_max(self) -> np.float32:
        return logodds(self.clamp_max)
