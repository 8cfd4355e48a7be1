"""Settings of what the vehicle senses: the sonar and the navigation's drift."""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from vogjax.config.schema import Config, integer, non_negative, number, positive

# Beams per scan a run file holds (vogjax.io.dataset); a sonar's beams times its sub-rays too.
MAX_BEAMS = 1 << 20


@dataclasses.dataclass(frozen=True)
class NavNoise(Config):
    """Navigation drift per second of travel (Sodhi et al., Eq. 10).

    x, y and yaw drift (relative xyh factors); z, pitch and roll are measured absolutely (depth
    sensor, inclinometers: unary zpr factors). The defaults are the paper's.

    Attributes
    ----------
    sigma2_x : float
        Variance of the x drift per second of travel, m^2/s.
    sigma2_y : float
        Variance of the y drift per second of travel, m^2/s.
    sigma2_yaw : float
        Variance of the yaw drift per second of travel, rad^2/s.
    sigma2_z : float
        Variance of the absolute z (depth) measurement per second since the previous pose, m^2/s.
    sigma2_pitch : float
        Variance of the absolute pitch measurement per second since the previous pose, rad^2/s.
    sigma2_roll : float
        Variance of the absolute roll measurement per second since the previous pose, rad^2/s.
    """

    sigma2_x: float = positive(0.00138, doc="in m^2/s")
    sigma2_y: float = positive(0.00138, doc="in m^2/s")
    sigma2_yaw: float = positive(1e-7, doc="in rad^2/s")
    sigma2_z: float = positive(1e-4, doc="in m^2/s")
    sigma2_pitch: float = positive(1e-7, doc="in rad^2/s")
    sigma2_roll: float = positive(1e-7, doc="in rad^2/s")

    def xyh_variances(self, duration_s: float) -> npt.NDArray[np.float64]:
        """Variances of the x, y and yaw drift accumulated over a duration.

        Parameters
        ----------
        duration_s : float
            Time travelled, seconds.

        Returns
        -------
        (3,) ndarray of float64
            ``[sigma2_x, sigma2_y, sigma2_yaw] * duration_s``: m^2, m^2, rad^2.
        """
        return np.array([self.sigma2_x, self.sigma2_y, self.sigma2_yaw]) * duration_s

    def zpr_variances(self, duration_s: float) -> npt.NDArray[np.float64]:
        """Variances of the z, pitch and roll measurements over a duration.

        Parameters
        ----------
        duration_s : float
            Time between the two poses, seconds.

        Returns
        -------
        (3,) ndarray of float64
            ``[sigma2_z, sigma2_pitch, sigma2_roll] * duration_s``: m^2, rad^2, rad^2.
        """
        return np.array([self.sigma2_z, self.sigma2_pitch, self.sigma2_roll]) * duration_s


@dataclasses.dataclass(frozen=True)
class SonarConfig(Config):
    """A profiling sonar rolled 90 degrees so its fan is vertical, looking ahead (Ho, thesis 4.1).

    Attributes
    ----------
    beams : int
        Beams per scan, spread over `fov_deg` in the vehicle's x-z plane.
    fov_deg : float
        Angle the fan of beams spans, degrees.
    tilt_deg : float
        Angle of the fan's centre above the horizontal, degrees (negative: looking down).
    rate_hz : float
        Scans per second.
    min_range_m : float
        Shortest return, metres; nearer surfaces give no return.
    max_range_m : float
        Longest return, metres: the sonar's reach.
    range_noise_m : float
        Standard deviation of the Gaussian range noise, metres (0: exact ranges).
    aperture_deg : float
        Width of each beam across the fan, degrees, sampled by `subrays` rays.
    subrays : int
        Rays cast per beam across its aperture; the nearest return is kept (1: a line sensor, as
        the papers simulate).

    Raises
    ------
    ValueError
        If a setting is out of its range, `min_range_m` is not below `max_range_m`, or
        ``beams * subrays`` exceeds MAX_BEAMS (2^20).
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
