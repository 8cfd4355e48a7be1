"""Frozen configuration dataclasses."""

from __future__ import annotations

import dataclasses
import math

import numpy as np


def logodds(probability: float) -> np.float32:
    """Log-odds of a probability, rounded to float32 the way OctoMap stores it."""
    return np.float32(math.log(probability / (1.0 - probability)))


@dataclasses.dataclass(frozen=True)
class MapConfig:
    """Occupancy map parameters. Defaults are those of Sodhi et al. (IV-C) with OctoMap's clamping.

    voxel_size:          edge of a voxel, metres; voxel k covers [k*s, (k+1)*s) on each axis
    prob_hit, prob_miss: inverse sensor model for the endpoint and the cells a beam crosses
    occupied_threshold:  probability at or above which a voxel is OCCUPIED
    free_threshold:      probability at or below which a voxel is FREE (between: UNKNOWN)
    clamp_min, clamp_max: probabilities the log-odds are clamped to after every update
    max_range:           beams longer than this give free space up to it and no hit, metres
    """

    voxel_size: float = 0.1
    prob_hit: float = 0.75
    prob_miss: float = 0.2
    occupied_threshold: float = 0.7
    free_threshold: float = 0.3
    clamp_min: float = 0.1192
    clamp_max: float = 0.971
    max_range: float = 11.0

    def __post_init__(self):
        for name in ("voxel_size", "max_range"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0 and not math.isnan(value)):
                raise ValueError(f"MapConfig.{name} must be a positive number, got {value!r}")
        if not math.isfinite(self.voxel_size) or self.voxel_size < 1e-4:
            raise ValueError(f"MapConfig.voxel_size must be finite and >= 1e-4 m, got {self.voxel_size!r}")
        for name in ("prob_hit", "prob_miss", "occupied_threshold", "free_threshold",
                     "clamp_min", "clamp_max"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0.0 < value < 1.0):
                raise ValueError(f"MapConfig.{name} must lie strictly between 0 and 1, got {value!r}")
        if not self.prob_miss < 0.5 < self.prob_hit:
            raise ValueError("MapConfig.prob_hit must exceed 0.5 and MapConfig.prob_miss lie below it")
        if not self.free_threshold <= self.occupied_threshold:
            raise ValueError("MapConfig.free_threshold must not exceed MapConfig.occupied_threshold")
        if not self.clamp_min < self.clamp_max:
            raise ValueError("MapConfig.clamp_min must lie below MapConfig.clamp_max")

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

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict) -> "MapConfig":
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown MapConfig keys: {', '.join(unknown)}")
        return cls(**values)


@dataclasses.dataclass(frozen=True)
class NavNoise:
    """Navigation drift per second of travel (Sodhi et al., Eq. 10; variances in m^2/s, rad^2/s).

    x, y and yaw drift (relative xyh factors); z, pitch and roll are measured absolutely
    (depth sensor, inclinometers: unary zpr factors).
    """

    sigma2_x: float = 0.00138
    sigma2_y: float = 0.00138
    sigma2_yaw: float = 1e-7
    sigma2_z: float = 1e-4
    sigma2_pitch: float = 1e-7
    sigma2_roll: float = 1e-7

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"NavNoise.{field.name} must be a positive number, got {value!r}")

    def xyh_variances(self, duration_s: float) -> np.ndarray:
        return np.array([self.sigma2_x, self.sigma2_y, self.sigma2_yaw]) * duration_s

    def zpr_variances(self, duration_s: float) -> np.ndarray:
        return np.array([self.sigma2_z, self.sigma2_pitch, self.sigma2_roll]) * duration_s

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True)
class SonarConfig:
    """A profiling sonar rolled 90 degrees so its fan is vertical, looking ahead (Ho, thesis 4.1).

    beams over fov_deg in the vehicle's x-z plane, centred tilt_deg above the horizontal;
    rate_hz scans per second; returns between min_range_m and max_range_m; range_noise_m
    Gaussian range noise; aperture_deg across the fan sampled by `subrays` rays (nearest return
    kept; 1 sub-ray: a line sensor, as the papers simulate).
    """

    beams: int = 96
    fov_deg: float = 29.0
    tilt_deg: float = -10.0
    rate_hz: float = 5.0
    min_range_m: float = 0.5
    max_range_m: float = 11.0
    range_noise_m: float = 0.0
    aperture_deg: float = 1.0
    subrays: int = 1

    def __post_init__(self):
        if not (isinstance(self.beams, int) and self.beams >= 1):
            raise ValueError(f"SonarConfig.beams must be a positive integer, got {self.beams!r}")
        if not (isinstance(self.subrays, int) and self.subrays >= 1):
            raise ValueError(f"SonarConfig.subrays must be a positive integer, got {self.subrays!r}")
        for name in ("fov_deg", "rate_hz", "max_range_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"SonarConfig.{name} must be positive, got {getattr(self, name)!r}")
        if not 0 <= self.min_range_m < self.max_range_m:
            raise ValueError("SonarConfig.min_range_m must lie in [0, max_range_m)")
        if self.range_noise_m < 0 or self.aperture_deg < 0:
            raise ValueError("SonarConfig.range_noise_m and aperture_deg must be >= 0")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def replace_from_dict(config, values: dict, where: str):
    """A copy of the frozen dataclass `config` with `values` (nested dicts for nested
    dataclasses) replacing its fields. Unknown keys and values of the wrong type are
    ValueErrors naming the key as `where.key`."""
    if not isinstance(values, dict):
        raise ValueError(f"{where} must be a table of settings, got {values!r}")
    fields = {f.name: f for f in dataclasses.fields(config)}
    changes = {}
    for key, value in values.items():
        name = f"{where}.{key}"
        if key not in fields:
            raise ValueError(f"unknown setting {name} (known: {', '.join(sorted(fields))})")
        current = getattr(config, key)
        if dataclasses.is_dataclass(current):
            changes[key] = replace_from_dict(current, value, name)
        elif isinstance(current, bool) or isinstance(value, bool):
            if not isinstance(value, bool) or not isinstance(current, bool):
                raise ValueError(f"{name} must be {type(current).__name__}, got {value!r}")
            changes[key] = value
        elif isinstance(current, float) and isinstance(value, int):
            changes[key] = float(value)
        elif current is not None and not isinstance(value, type(current)) and not isinstance(current, str):
            raise ValueError(f"{name} must be {type(current).__name__}, got {value!r}")
        else:
            changes[key] = value
    try:
        return dataclasses.replace(config, **changes)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{where}: {error}") from None
