"""A recorded range sensor whose beams change from scan to scan: a lidar's point cloud or a
laser scanner's fan, as `vogjax import` brings them from ROS bags.

Its run file stores every scan's own beam directions, so the sensor has no fixed beam pattern
to simulate; it tells the mapper its reach (`max_range_m`) and its mount.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from vogjax.config.point_cloud import PointCloudConfig
from vogjax.sensors.base import RangeSensor


class PointCloudSensor(RangeSensor):
    """A recorded point-cloud sensor (an imported lidar, depth camera or laser scan): its beams
    are stored per scan.

    Parameters
    ----------
    config : PointCloudConfig or None, optional
        Its settings.
    T_vehicle_sensor : (4, 4) array_like of float or None, optional
        Its mount (from TF; default: the vehicle frame).

    Raises
    ------
    ValueError
        If `config` is not a PointCloudConfig or the mount is not rigid.
    """

    kind = "point_cloud"

    def __init__(self, config: PointCloudConfig | None = None, T_vehicle_sensor: npt.ArrayLike | None = None):
        config = config or PointCloudConfig()
        if not isinstance(config, PointCloudConfig):
            raise ValueError(f"config must be a PointCloudConfig, got {type(config).__name__}")
        super().__init__(config, T_vehicle_sensor)

    @property
    def beams(self) -> int:
        """Beams a scan."""
        return self.config.beams

    def beam_directions(self) -> np.ndarray:
        """None: a recorded sensor's beams are in its run file.

        Returns
        -------
        ndarray
            Never.

        Raises
        ------
        ValueError
            Always: it cannot be simulated.
        """
        raise ValueError(
            "a recorded point-cloud sensor has no fixed beams: its run file stores each scan's "
            "beam directions (it cannot be simulated)"
        )
