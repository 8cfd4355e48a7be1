"""A spinning lidar: rings of lasers on a turning head, fired column by column over the sweep.

Beam b of a scan is ring ``b % rings`` of column ``b // rings``; column c fires at
``c / (columns * rate_hz)`` seconds after the scan's stamp, at azimuth ``c * column_deg``
(counter-clockwise from the sensor's x axis). A vehicle that moves during the sweep carries
every column from its own pose: the simulator casts each column from where the sensor was when
it fired (`vogjax.sim.lidar_mission`), and the run stores the points as the sensor reports them
in its frame at the stamp, or deskewed with the odometry as `vogjax import` deskews clouds.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from vogjax.config.lidar import LidarConfig
from vogjax.sensors.base import RangeSensor

# On a ground vehicle: 0.3 m ahead of its base's centre, 1.8 m above the floor.
T_VEHICLE_LIDAR = np.eye(4)
T_VEHICLE_LIDAR[:3, 3] = [0.3, 0.0, 1.8]


class SpinningLidar(RangeSensor):
    """LidarConfig's rings and columns; mounted at T_vehicle_sensor (default: on the vehicle's roof).

    Parameters
    ----------
    config : LidarConfig or None, optional
        The lidar's settings (default: a 16-ring, 0.4 degree, 10 Hz, 0.5-50 m lidar).
    T_vehicle_sensor : (4, 4) array_like of float or None, optional
        Its mount on the vehicle (default `T_VEHICLE_LIDAR`).

    Raises
    ------
    ValueError
        If `config` is not a LidarConfig or the mount is not rigid.
    """

    kind = "spinning_lidar"

    def __init__(self, config: LidarConfig | None = None, T_vehicle_sensor: npt.ArrayLike | None = None):
        config = config or LidarConfig()
        if not isinstance(config, LidarConfig):
            raise ValueError(f"config must be a LidarConfig, got {type(config).__name__}")
        super().__init__(config, T_VEHICLE_LIDAR if T_vehicle_sensor is None else T_vehicle_sensor)

    @property
    def beams(self) -> int:
        """Beams a scan."""
        return self.config.columns * self.config.rings

    def ring_directions(self) -> npt.NDArray[np.float64]:
        """The rings' unit directions at azimuth 0 (the first column), sensor frame.

        Returns
        -------
        (rings, 3) ndarray of float64
            Lowest ring first.
        """
        cfg = self.config
        half = cfg.fov_deg / 2
        elevation = np.deg2rad(cfg.tilt_deg + (np.linspace(-half, half, cfg.rings) if cfg.rings > 1 else np.zeros(1)))
        return np.stack([np.cos(elevation), np.zeros_like(elevation), np.sin(elevation)], axis=-1)

    def azimuths_rad(self) -> npt.NDArray[np.float64]:
        """Each column's azimuth, radians, counter-clockwise from the sensor's x axis.

        Returns
        -------
        (columns,) ndarray of float64
            ``c * column_deg`` in radians.
        """
        return np.deg2rad(np.arange(self.config.columns) * self.config.column_deg)

    def column_offsets_s(self) -> npt.NDArray[np.float64]:
        """When each column fires, after the scan's stamp.

        Returns
        -------
        (columns,) ndarray of float64
            ``c / (columns * rate_hz)`` seconds, in [0, 1 / rate_hz).
        """
        return np.arange(self.config.columns) / (self.config.columns * self.config.rate_hz)

    def firing_offsets_s(self) -> npt.NDArray[np.float64]:
        """When each beam fires, after the scan's stamp (the rings of a column at once).

        Returns
        -------
        (B,) ndarray of float64
            Seconds, in beam order (column-major).
        """
        return np.repeat(self.column_offsets_s(), self.config.rings)

    def rings_of_beams(self) -> npt.NDArray[np.uint16]:
        """The ring (laser) of each beam, as the run's `ring` field stores it.

        Returns
        -------
        (B,) ndarray of uint16
            ``b % rings``, lowest ring 0.
        """
        return np.tile(np.arange(self.config.rings, dtype=np.uint16), self.config.columns)

    def beam_directions(self) -> npt.NDArray[np.float64]:
        """Every beam's unit direction in the sensor frame, one ray each.

        Returns
        -------
        (B, 1, 3) ndarray of float64
            Column-major: beam ``c * rings + r`` is ring r turned by column c's azimuth.
        """
        azimuth = self.azimuths_rad()
        rings = self.ring_directions()
        c, s = np.cos(azimuth)[:, None], np.sin(azimuth)[:, None]
        x, z = rings[None, :, 0], rings[None, :, 2]
        directions = np.stack([c * x, s * x, np.broadcast_to(z, (len(azimuth), len(rings)))], axis=-1)
        return directions.reshape(-1, 1, 3)
