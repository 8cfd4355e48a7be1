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
import numpy.typing as npt

from vogjax.config import Config
from vogjax.geometry import rigid_pose


class RangeSensor(abc.ABC):
    """A range sensor: its beams, rate, ranges and mount.

    Parameters
    ----------
    config : Config
        The sensor's settings.
    T_vehicle_sensor : (4, 4) array_like of float or None, optional
        Where it is mounted on the vehicle (default: the vehicle's origin).

    Attributes
    ----------
    kind : str
        The sensor's name in run files and `vogjax.sensors.KINDS`.
    config : Config
        The sensor's settings.
    T_vehicle_sensor : (4, 4) ndarray of float64
        Its mount.

    Raises
    ------
    ValueError
        If `T_vehicle_sensor` is not a rigid pose.
    """

    kind: str = ""

    def __init__(self, config: Config, T_vehicle_sensor: npt.ArrayLike | None = None):
        self.config = config
        self.T_vehicle_sensor = rigid_pose(
            "T_vehicle_sensor", np.eye(4) if T_vehicle_sensor is None else T_vehicle_sensor
        )

    @property
    @abc.abstractmethod
    def beams(self) -> int:
        """Beams a scan, B."""

    @property
    @abc.abstractmethod
    def rate_hz(self) -> float:
        """Scans a second."""

    @property
    @abc.abstractmethod
    def min_range_m(self) -> float:
        """Nearest range it measures, metres."""

    @property
    @abc.abstractmethod
    def max_range_m(self) -> float:
        """Farthest range it measures, metres."""

    @property
    def range_noise_m(self) -> float:
        """Standard deviation of its simulated range noise, metres (0: none)."""
        return 0.0

    @abc.abstractmethod
    def beam_directions(self) -> np.ndarray:
        """The beams' directions: B beams of U sub-rays each (the beam's aperture; a simulated
        beam returns its nearest sub-ray's range).

        Returns
        -------
        (B, U, 3) ndarray of float64
            Unit directions in the sensor frame.
        """

    def dataset_fields(self, ranges: npt.ArrayLike, no_return: npt.ArrayLike) -> dict:
        """The run-file fields of S scans: origin and the central direction of each beam in the
        vehicle frame, ranges (NaN where no return).

        Parameters
        ----------
        ranges : (S, B) array_like of float
            Measured ranges, metres.
        no_return : (S, B) array_like of bool
            Beams without a return.

        Returns
        -------
        dict
            ``sonar_origin`` (S, 3), ``sonar_directions`` (S, B, 3), ``ranges`` (S, B) and
            ``no_return`` (S, B), as the run file stores them.
        """
        ranges, no_return = np.asarray(ranges), np.asarray(no_return)
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
        """What a run file records of the sensor (read back by `vogjax.sensors.from_metadata`).

        Returns
        -------
        dict
            ``sensor`` (its kind), ``sensor_config`` (its settings) and ``T_vehicle_sensor``.
        """
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
    """Sensor origins and beam endpoints in the world frame of S scans.

    Beams without a return end past `max_range_m`, so a map clears free space up to its range
    along them and marks nothing occupied.

    Parameters
    ----------
    T_world_vehicle : (S, 4, 4) ndarray of float64
        The vehicle's poses.
    origins : (S, 3) ndarray of float64
        The sensor's origin in the vehicle frame, per scan.
    directions : (S, B, 3) ndarray of float64
        Unit beam directions in the vehicle frame.
    ranges : (S, B) ndarray of float64
        Measured ranges, metres.
    no_return : (S, B) ndarray of bool
        Beams without a return.
    max_range_m : float
        The map's reach, metres.

    Returns
    -------
    origins : (S, 3) ndarray of float64
        The sensor's origins, world frame.
    endpoints : (S, B, 3) ndarray of float64
        The beams' end points, world frame.
    """
    R, t = T_world_vehicle[:, :3, :3], T_world_vehicle[:, :3, 3]
    world_origins = np.einsum("sij,sj->si", R, origins) + t
    world_directions = np.einsum("sij,sbj->sbi", R, directions)
    lengths = np.where(no_return, max_range_m * 1.05 + 0.1, ranges)
    return world_origins, world_origins[:, None] + world_directions * lengths[..., None]
