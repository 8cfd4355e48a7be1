"""What every range sensor tells the rest of vogjax.

A range sensor sends beams from one origin and measures a range per beam (NaN / no return when
nothing lies within its range). The simulator casts its beams (`beam_directions`), the run
file stores each scan's origin, beam directions and ranges in the vehicle frame
(`dataset_fields`) with the sensor described in the metadata (`metadata`), and the mapper turns
stored scans into world rays (`world_rays`). A new sensor subclasses `RangeSensor` and registers
its `kind` in `vogjax.sensors.KINDS`.
"""

from __future__ import annotations

import abc

import numpy as np

from vogjax.config import Config
from vogjax.geometry import rigid_pose


class RangeSensor(abc.ABC):
    """config: the sensor's settings; T_vehicle_sensor (4,4): where it is mounted."""

    kind: str = ""

    def __init__(self, config: Config, T_vehicle_sensor=None):
        self.config = config
        self.T_vehicle_sensor = rigid_pose(
            "T_vehicle_sensor", np.eye(4) if T_vehicle_sensor is None else T_vehicle_sensor
        )

    @property
    @abc.abstractmethod
    def beams(self) -> int: ...

    @property
    @abc.abstractmethod
    def rate_hz(self) -> float: ...

    @property
    @abc.abstractmethod
    def min_range_m(self) -> float: ...

    @property
    @abc.abstractmethod
    def max_range_m(self) -> float: ...

    @property
    def range_noise_m(self) -> float:
        return 0.0

    @abc.abstractmethod
    def beam_directions(self) -> np.ndarray:
        """(B, U, 3) unit directions in the sensor frame: B beams of U sub-rays each (the
        beam's aperture; a simulated beam returns its nearest sub-ray's range)."""

    def dataset_fields(self, ranges: np.ndarray, no_return: np.ndarray) -> dict:
        """The run-file fields of S scans with ranges and no_return (S, B): origin and the
        central direction of each beam in the vehicle frame, ranges (NaN where no return)."""
        count = len(ranges)
        central = self.beam_directions()[:, self.beam_directions().shape[1] // 2]
        directions = central @ self.T_vehicle_sensor[:3, :3].T
        return {
            "sonar_origin": np.tile(self.T_vehicle_sensor[:3, 3], (count, 1)),
            "sonar_directions": np.tile(directions, (count, 1, 1)),
            "ranges": np.where(no_return, np.nan, ranges),
            "no_return": no_return,
        }

    def metadata(self) -> dict:
        """What a run file records of the sensor (read back by `vogjax.sensors.from_metadata`)."""
        return {
            "sensor": self.kind,
            "sensor_config": self.config.to_dict(),
            "T_vehicle_sensor": self.T_vehicle_sensor.tolist(),
        }


def world_rays(
    T_world_vehicle: np.ndarray,
    origins: np.ndarray,
    directions: np.ndarray,
    ranges: np.ndarray,
    no_return: np.ndarray,
    max_range_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Sensor origins (S,3) and beam endpoints (S,B,3) in the world frame of S scans: vehicle
    poses (S,4,4), origins (S,3) and unit directions (S,B,3) in the vehicle frame, ranges and
    no_return (S,B). Beams without a return end past `max_range_m`, so a map clears free space
    up to its range along them and marks nothing occupied."""
    R, t = T_world_vehicle[:, :3, :3], T_world_vehicle[:, :3, 3]
    world_origins = np.einsum("sij,sj->si", R, origins) + t
    world_directions = np.einsum("sij,sbj->sbi", R, directions)
    lengths = np.where(no_return, max_range_m * 1.05 + 0.1, ranges)
    return world_origins, world_origins[:, None] + world_directions * lengths[..., None]
