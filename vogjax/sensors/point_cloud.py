"""A recorded range sensor whose beams change from scan to scan: a lidar's point cloud or a
laser scanner's fan, as `vogjax import` brings them from ROS bags.

Its run file stores every scan's own beam directions, so the sensor has no fixed beam pattern
to simulate; it tells the mapper its reach (`max_range_m`) and its mount.
"""

from __future__ import annotations

import numpy as np

from vogjax.config.point_cloud import PointCloudConfig
from vogjax.sensors.base import RangeSensor


class PointCloudSensor(RangeSensor):
    """Settings in a PointCloudConfig; mounted at T_vehicle_sensor (from TF, or the vehicle frame)."""

    kind = "point_cloud"

    def __init__(self, config: PointCloudConfig | None = None, T_vehicle_sensor=None):
        config = config or PointCloudConfig()
        if not isinstance(config, PointCloudConfig):
            raise ValueError(f"config must be a PointCloudConfig, got {type(config).__name__}")
        super().__init__(config, T_vehicle_sensor)

    beams = property(lambda self: self.config.beams)
    rate_hz = property(lambda self: self.config.rate_hz)
    min_range_m = property(lambda self: self.config.min_range_m)
    max_range_m = property(lambda self: self.config.max_range_m)

    def beam_directions(self) -> np.ndarray:
        raise ValueError(
            "a recorded point-cloud sensor has no fixed beams: its run file stores each scan's "
            "beam directions (it cannot be simulated)"
        )
