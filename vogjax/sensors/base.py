"""What every range sensor tells the rest of vogjax.

A range sensor sends beams from one origin and measures a range per beam: a return, no return
(nothing lies within its range: the beam saw water up to it), or an invalid beam (its surface
lies within the sensor's blind distance, `min_range_m`: the echo is lost, and the beam tells
nothing about the water along it). The simulator casts its beams (`beam_directions`), the run
file stores each scan's origin, beam directions and ranges in the vehicle frame
(`dataset_fields`) with the sensor described in the metadata (`metadata`), and the mapper turns
stored scans into world rays (`world_rays`, `mapped_beams`): free space up to a return or along
a beam without one, never along an invalid beam. A new sensor subclasses `RangeSensor` and registers
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

    # every sensor's settings carry these under the same names
    @property
    def rate_hz(self) -> float:
        """Scans a second (its settings' `rate_hz`)."""
        return self.config.rate_hz

    @property
    def min_range_m(self) -> float:
        """Nearest range it measures, metres (its settings' `min_range_m`)."""
        return self.config.min_range_m

    @property
    def max_range_m(self) -> float:
        """Farthest range it measures, metres (its settings' `max_range_m`)."""
        return self.config.max_range_m

    @property
    def range_noise_m(self) -> float:
        """Standard deviation of its simulated range noise, metres (0: none, as for a recorded sensor)."""
        return getattr(self.config, "range_noise_m", 0.0)

    @abc.abstractmethod
    def beam_directions(self) -> np.ndarray:
        """The beams' directions: B beams of U sub-rays each (the beam's aperture; a simulated
        beam returns its nearest sub-ray's range).

        Returns
        -------
        (B, U, 3) ndarray of float64
            Unit directions in the sensor frame.
        """

    def beam_axes(self) -> np.ndarray:
        """Each beam's axis, the direction its range is recorded along: the central sub-ray
        of an odd number, the normalised mean of an even number (whose middle index is an
        edge ray, half the aperture off the axis).

        Returns
        -------
        (beams, 3) ndarray of float64
            Unit directions in the sensor frame.
        """
        rays = self.beam_directions()
        if rays.shape[1] % 2:
            return rays[:, rays.shape[1] // 2]
        mean = rays.mean(axis=1)
        return mean / np.linalg.norm(mean, axis=1, keepdims=True)

    def dataset_fields(
        self, ranges: npt.ArrayLike, no_return: npt.ArrayLike, invalid: npt.ArrayLike | None = None
    ) -> dict:
        """The run-file fields of S scans of this sensor's B beams.

        Parameters
        ----------
        ranges : (S, B) array_like of float
            Measured ranges, metres (ignored where `no_return` or `invalid`).
        no_return : (S, B) array_like of bool
            Beams without a return.
        invalid : (S, B) array_like of bool, optional
            Beams whose surface lies within the blind distance (default: none).

        Returns
        -------
        dict
            ``sonar_origin`` (S, 3) and ``sonar_directions`` (S, B, 3), the origin and the
            central direction of each beam in the vehicle frame; ``ranges`` (S, B), NaN where
            there is no return or the beam is invalid; ``no_return`` and ``invalid`` (S, B).
        """
        no_return = np.asarray(no_return, dtype=bool)
        invalid = np.zeros_like(no_return) if invalid is None else np.asarray(invalid, dtype=bool)
        count = len(no_return)
        directions = self.beam_axes() @ self.T_vehicle_sensor[:3, :3].T
        return {
            "sonar_origin": np.tile(self.T_vehicle_sensor[:3, 3], (count, 1)),
            "sonar_directions": np.tile(directions, (count, 1, 1)),
            "ranges": np.where(no_return | invalid, np.nan, ranges),
            "no_return": no_return & ~invalid,
            "invalid": invalid,
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


# Beams world_rays transforms at a time.
RAYS_PER_CHUNK = 1 << 15


def world_rays(
    T_world_vehicle: np.ndarray,
    origins: np.ndarray,
    directions: np.ndarray,
    ranges: np.ndarray,
    no_return: np.ndarray,
    max_range_m: float,
    invalid: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Sensor origins and beam endpoints in the world frame of S scans of B beams.

    Parameters
    ----------
    T_world_vehicle : numpy.ndarray, (S, 4, 4) float
        Vehicle poses.
    origins, directions : numpy.ndarray, (S, 3) and (S, B, 3) float
        Sensor origin and unit beam directions in the vehicle frame.
    ranges, no_return : numpy.ndarray, (S, B)
        Metres per beam; beams without a return.
    max_range_m : float
        The reach a beam without a return clears free space to.
    invalid : numpy.ndarray, (S, B) bool, optional
        Beams whose surface lay within the sensor's blind distance (default: none).

    Returns
    -------
    origins : numpy.ndarray, (S, 3) float
    endpoints : numpy.ndarray, (S, B, 3) float
        Beams without a return end past `max_range_m` (a map clears free space up to its range
        along them and marks nothing occupied); invalid beams end at NaN, which every map
        refuses: drop them first (`mapped_beams`), nothing may be cleared along them.
    """
    R, t = T_world_vehicle[:, :3, :3], T_world_vehicle[:, :3, 3]
    world_origins = np.einsum("sij,sj->si", R, origins) + t
    lengths = np.where(no_return, max_range_m * 1.05 + 0.1, ranges)
    if invalid is not None:
        lengths = np.where(invalid, np.nan, lengths)
    count, beams = np.shape(directions)[:2]
    endpoints = np.empty((count, beams, 3), np.float64)
    # A few scans at a time, so the temporaries stay in cache: a lidar scan holds 10-30k beams,
    # and one einsum over a whole batch made this step cost half as much as integrating it.
    # Each endpoint is o_i + ((R_i0 d_0 + R_i2 d_2) + R_i1 d_1) L in float64, in that order on
    # every machine and batch size; it is the order the einsum took, so runs mapped before
    # give the same bits (checked on a sonar and a lidar run, docs/benchmarks/lidar.md).
    step = max(1, RAYS_PER_CHUNK // max(beams, 1))
    for lo in range(0, count, step):
        rows = slice(lo, lo + step)
        r, d, length = R[rows, None], directions[rows], lengths[rows]
        for i in range(3):
            rotated = r[..., i, 0] * d[..., 0] + r[..., i, 2] * d[..., 2]
            rotated += r[..., i, 1] * d[..., 1]
            rotated *= length
            endpoints[rows, :, i] = world_origins[rows, None, i] + rotated
    return world_origins, endpoints


def mapped_beams(
    origins: np.ndarray, endpoints: np.ndarray, invalid: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The beams a map integrates: every beam of S scans but the invalid ones.

    Parameters
    ----------
    origins : numpy.ndarray, (S, 3) float
        Sensor origin per scan (`world_rays`).
    endpoints : numpy.ndarray, (S, B, 3) float
        Beam endpoints (`world_rays`).
    invalid : numpy.ndarray, (S, B) bool, optional
        Beams to leave out (default: none).

    Returns
    -------
    origins : numpy.ndarray, (S, 3) float
    points : numpy.ndarray, (N, 3) float
        The endpoints of the valid beams, scan by scan.
    scan_index : numpy.ndarray, (N,) int64
        The scan of each point, for ``integrate_scans``.
    """
    count, beams = endpoints.shape[:2]
    scan_index = np.repeat(np.arange(count), beams)
    points = endpoints.reshape(-1, 3)
    if invalid is not None and np.any(invalid):
        keep = ~np.asarray(invalid, dtype=bool).reshape(-1)
        points, scan_index = points[keep], scan_index[keep]
    return origins, points, scan_index
