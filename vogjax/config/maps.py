"""Settings of the occupancy maps."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from vogjax.config.schema import Config, number, positive, probability

# A beam crosses at most this many voxels: integration's scratch grows with it (4096 voxels at
# 0.1 m: 410 m, beyond any sonar or most lidars).
MAX_RANGE_VOXELS = 4096


def logodds(probability: float) -> np.float32:
    """Log-odds of a probability, rounded to float32 the way OctoMap stores it.

    Parameters
    ----------
    probability : float
        A probability in [0, 1].

    Returns
    -------
    numpy.float32
        ``log(p / (1 - p))``; -inf at 0 and +inf at 1 (or beyond), so clamping at those
        probabilities clamps nothing.

    Examples
    --------
    >>> float(logodds(0.5))
    0.0
    """
    if probability <= 0.0:
        return np.float32(-np.inf)
    if probability >= 1.0:
        return np.float32(np.inf)
    return np.float32(math.log(probability / (1.0 - probability)))


@dataclasses.dataclass(frozen=True)
class MapConfig(Config):
    """Settings of the log-odds occupancy maps (`vj.VoxelMap`, `vj.VogMap`, `vj.GlobalMap`).

    Defaults are those of Sodhi et al. (IV-C) with OctoMap's clamping; `MapConfig.paper()` drops
    the clamping, as the paper does.

    Attributes
    ----------
    voxel_size : float
        Edge of a voxel, metres; voxel k covers ``[k*s, (k+1)*s)`` on each axis.
    prob_hit : float
        Inverse sensor model: occupancy probability a beam's endpoint gives its voxel.
    prob_miss : float
        Inverse sensor model: occupancy probability a beam gives each voxel it crosses before
        its endpoint.
    occupied_threshold : float
        Probability at or above which a voxel is OCCUPIED.
    free_threshold : float
        Probability at or below which a voxel is FREE (between the thresholds: UNKNOWN).
    clamp_min : float
        Probability the log-odds are clamped up to after every update; 0 clamps nothing (Sodhi et
        al.'s p_min = 0: `MapConfig.paper()`). The default is OctoMap's.
    clamp_max : float
        Probability the log-odds are clamped down to after every update; 1 clamps nothing (Sodhi
        et al.'s p_max = 1). The default is OctoMap's.
    max_range : float
        Beams longer than this give free space up to it and no hit, metres; at most 4096 voxels
        (integration allocates per beam for every block a beam may cross).

    Raises
    ------
    ValueError
        If a setting is out of its range, `prob_hit` is not above 0.5 or `prob_miss` not below
        it, `free_threshold` exceeds `occupied_threshold`, `clamp_min` is not below `clamp_max`,
        or `max_range` exceeds 4096 voxels.
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
    def paper(cls, **changes: Any) -> MapConfig:
        """The settings of Sodhi et al. IV-C.

        10 cm voxels, hit/miss 0.75/0.2, thresholds 0.7/0.3, and no clamping (p_min = 0,
        p_max = 1), which keeps every update invertible.

        Parameters
        ----------
        **changes
            Settings that replace the paper's.

        Returns
        -------
        MapConfig
            The paper's settings with `changes` applied.
        """
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

    @property
    def log_hit(self) -> np.float32:
        """Log-odds of `prob_hit`, float32 like the stored values."""
        return logodds(self.prob_hit)

    @property
    def log_miss(self) -> np.float32:
        """Log-odds of `prob_miss`, float32 like the stored values."""
        return logodds(self.prob_miss)

    @property
    def log_occupied(self) -> np.float32:
        """Log-odds of `occupied_threshold`, float32 like the stored values."""
        return logodds(self.occupied_threshold)

    @property
    def log_free(self) -> np.float32:
        """Log-odds of `free_threshold`, float32 like the stored values."""
        return logodds(self.free_threshold)

    @property
    def log_clamp_min(self) -> np.float32:
        """Log-odds of `clamp_min` (-inf at 0: no clamping), float32 like the stored values."""
        return logodds(self.clamp_min)

    @property
    def log_clamp_max(self) -> np.float32:
        """Log-odds of `clamp_max` (+inf at 1: no clamping), float32 like the stored values."""
        return logodds(self.clamp_max)
