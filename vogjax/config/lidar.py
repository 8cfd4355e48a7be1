"""Settings of a spinning lidar: rings of lasers on a head that turns once per scan."""

from __future__ import annotations

import dataclasses

from vogjax.config.schema import Config, integer, non_negative, number, positive
from vogjax.config.sensing import MAX_BEAMS


@dataclasses.dataclass(frozen=True)
class LidarConfig(Config):
    """A spinning lidar: `rings` lasers spread over `fov_deg` of elevation, fired in columns
    `column_deg` apart while the head turns once per scan (a Velodyne VLP-16 by default).

    Attributes
    ----------
    rings : int
        Lasers (rings) per column.
    fov_deg : float
        Elevation the rings span, degrees, centred on `tilt_deg` (30: +-15 degrees).
    tilt_deg : float
        Elevation of the rings' centre above the sensor's x-y plane, degrees.
    column_deg : float
        Azimuth between two columns, degrees; 360 / column_deg columns a turn (a whole number).
    rate_hz : float
        Turns (scans) per second; the columns fire evenly over the turn, the first at the
        scan's stamp, counter-clockwise from the sensor's x axis.
    min_range_m : float
        Shortest range the sensor measures, metres: a surface nearer than that gives an invalid
        beam (no range, and no free space along it either).
    max_range_m : float
        Longest return, metres: the sensor's reach.
    range_noise_m : float
        Standard deviation of the Gaussian range noise, metres (0: exact ranges).

    Raises
    ------
    ValueError
        If a setting is out of its range, `min_range_m` is not below `max_range_m`,
        ``360 / column_deg`` is not a whole number, or the columns times the rings exceed
        MAX_BEAMS (2^20).
    """

    rings: int = integer(16, low=1, high=1024)
    fov_deg: float = number(30.0, low=0, high=180)
    tilt_deg: float = number(0.0, low=-90, high=90)
    column_deg: float = number(0.4, low=0.01, high=360)
    rate_hz: float = positive(10.0)
    min_range_m: float = non_negative(0.5)
    max_range_m: float = positive(50.0)
    range_noise_m: float = non_negative(0.0)

    @property
    def columns(self) -> int:
        """Columns fired per turn: 360 / column_deg."""
        return int(round(360.0 / self.column_deg))

    def check(self) -> None:
        if not self.min_range_m < self.max_range_m:
            raise ValueError("LidarConfig.min_range_m must lie in [0, max_range_m)")
        if abs(360.0 / self.column_deg - self.columns) > 1e-6 * self.columns:
            raise ValueError(f"LidarConfig.column_deg must divide 360 degrees, got {self.column_deg!r}")
        if self.columns * self.rings > MAX_BEAMS:
            raise ValueError(
                f"LidarConfig's columns times rings must be at most {MAX_BEAMS}, got {self.columns} x {self.rings}"
            )
