"""Settings of what the vehicle senses: the sonar and the navigation's drift."""

from __future__ import annotations

import dataclasses

import numpy as np

from vogjax.config.schema import Config, integer, non_negative, number, positive

# Beams per scan a run file holds (vogjax.io.dataset); a sonar's beams times its sub-rays too.
MAX_BEAMS = 1 << 20


@dataclasses.dataclass(frozen=True)
class NavNoise(Config):
    """Navigation drift per second of travel (Sodhi et al., Eq. 10; variances in m^2/s, rad^2/s).

    x, y and yaw drift (relative xyh factors); z, pitch and roll are measured absolutely
    (depth sensor, inclinometers: unary zpr factors).
    """

    sigma2_x: float = positive(0.00138, doc="in m^2/s")
    sigma2_y: float = positive(0.00138, doc="in m^2/s")
    sigma2_yaw: float = positive(1e-7, doc="in rad^2/s")
    sigma2_z: float = positive(1e-4, doc="in m^2/s")
    sigma2_pitch: float = positive(1e-7, doc="in rad^2/s")
    sigma2_roll: float = positive(1e-7, doc="in rad^2/s")

    def xyh_variances(self, duration_s: float) -> np.ndarray:
        return np.array([self.sigma2_x, self.sigma2_y, self.sigma2_yaw]) * duration_s

    def zpr_variances(self, duration_s: float) -> np.ndarray:
        return np.array([self.sigma2_z, self.sigma2_pitch, self.sigma2_roll]) * duration_s


@dataclasses.dataclass(frozen=True)
class SonarConfig(Config):
    """A profiling sonar rolled 90 degrees so its fan is vertical, looking ahead (Ho, thesis 4.1).

    beams over fov_deg in the vehicle's x-z plane, centred tilt_deg above the horizontal;
    rate_hz scans per second; returns between min_range_m and max_range_m; range_noise_m
    Gaussian range noise; aperture_deg across the fan sampled by `subrays` rays (nearest return
    kept; 1 sub-ray: a line sensor, as the papers simulate).
    """

    beams: int = integer(96, low=1, high=MAX_BEAMS)
    fov_deg: float = number(29.0, low=0, high=360, low_open=True)
    tilt_deg: float = number(-10.0, low=-180, high=180)
    rate_hz: float = positive(5.0)
    min_range_m: float = non_negative(0.5)
    max_range_m: float = positive(11.0)
    range_noise_m: float = non_negative(0.0)
    aperture_deg: float = number(1.0, low=0, high=180)
    subrays: int = integer(1, low=1, high=MAX_BEAMS)

    def check(self) -> None:
        if not self.min_range_m < self.max_range_m:
            raise ValueError("SonarConfig.min_range_m must lie in [0, max_range_m)")
        if self.beams * self.subrays > MAX_BEAMS:  # every sub-ray is cast: simulation and view gain
            raise ValueError(
                f"SonarConfig.beams times SonarConfig.subrays must be at most {MAX_BEAMS}, "
                f"got {self.beams} x {self.subrays}"
            )
