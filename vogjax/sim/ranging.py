"""Simulated range scans: any RangeSensor's beams cast against the scene mesh in Warp."""

from __future__ import annotations

import dataclasses

import numpy as np
import warp as wp

from vogjax import devices
from vogjax.config import SonarConfig
from vogjax.geometry import rigid_poses
from vogjax.kernels import ranging
from vogjax.sensors import RangeSensor, as_sensor

# Beams cast in one call: their ranges and directions take ~40 bytes each (670 MB).
MAX_CAST_BEAMS = 1 << 24


@dataclasses.dataclass(frozen=True)
class SimulatedScans:
    """S scans of B beams, world frame.

    Attributes
    ----------
    origins : (S, 3) ndarray of float64
        The sensor's origin at each scan.
    directions : (S, B, 3) ndarray of float64
        Unit beam directions.
    ranges : (S, B) ndarray of float64
        Ranges, metres (NaN where no return or invalid).
    no_return : (S, B) ndarray of bool
        Beams without a return: no surface within the sensor's range.
    invalid : (S, B) ndarray of bool
        Beams whose surface lies within the sensor's blind distance (`min_range_m`), or whose
        noisy range is negative: they measured nothing.
    """

    origins: np.ndarray
    directions: np.ndarray
    ranges: np.ndarray
    no_return: np.ndarray
    invalid: np.ndarray


def scan(
    mesh: wp.Mesh,
    T_world_sensor: np.ndarray,
    sensor: RangeSensor | SonarConfig,
    rng: np.random.Generator | None = None,
) -> SimulatedScans:
    """Scans from sensor poses, one per pose, all in one launch.

    Parameters
    ----------
    mesh : warp.Mesh
        The scene (`Scene.warp_mesh`).
    T_world_sensor : (S, 4, 4) ndarray of float64
        The sensor's poses: rigid (a scaled rotation would scale every range) and finite.
    sensor : RangeSensor or SonarConfig
        The sensor (a SonarConfig: the papers' profiling sonar with it).
    rng : numpy.random.Generator or None, optional
        Source of the range noise (None: no noise).

    Returns
    -------
    SimulatedScans
        The scans, world frame.

    Raises
    ------
    ValueError
        If `mesh` is not a warp.Mesh, the poses are not rigid and finite, `rng` is not a
        Generator, `sensor` is not a sensor, or the scans hold more than MAX_CAST_BEAMS beams.
    """
    if not isinstance(mesh, wp.Mesh):
        raise ValueError(f"mesh must be a warp.Mesh (a Scene's warp_mesh), got {type(mesh).__name__}")
    poses = rigid_poses("T_world_sensor", T_world_sensor)
    if rng is not None and not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator or None, got {type(rng).__name__}")
    sensor = as_sensor(sensor)
    if len(poses) * sensor.beams > MAX_CAST_BEAMS:
        raise ValueError(
            f"T_world_sensor holds {len(poses)} poses of {sensor.beams} beams each, more than "
            f"{MAX_CAST_BEAMS} beams in one call (scan fewer poses at a time)"
        )
    devices.init()
    count = len(poses)
    local = sensor.beam_directions()
    ranges = wp.empty((count, sensor.beams), dtype=float, device="cpu")
    if count:
        wp.launch(
            ranging.cast_sensor_beams,
            dim=(count, sensor.beams),
            inputs=[
                mesh.id,
                wp.array(poses[:, :3, 3], dtype=wp.vec3, device="cpu"),
                wp.array(poses[:, :3, :3], dtype=wp.mat33, device="cpu"),
                wp.array(local, dtype=wp.vec3, device="cpu"),
                float(sensor.min_range_m),
                float(sensor.max_range_m),
            ],
            outputs=[ranges],
            device="cpu",
        )
    ranges = ranges.numpy().astype(np.float64)
    no_return = ranges == ranging.NO_RETURN
    invalid = ranges == ranging.INVALID
    if sensor.range_noise_m > 0 and rng is not None:  # None: no noise, as documented (and the same bits)
        ranges = ranges + rng.normal(0.0, sensor.range_noise_m, ranges.shape)
        # a return the noise takes below zero measured nothing: an invalid beam, as the lidar's
        # simulation marks one it takes into the blind distance. Not at min_range_m as the lidar
        # does: the sonar's runs have always kept noisy returns just short of it (a few in a
        # thousand with the default 2 cm), and the same seed must give the same run
        invalid |= ~no_return & (ranges < 0.0)
        # and past its reach the sensor hears nothing: a return the noise takes beyond
        # max_range_m is no return (`max_range_m` is the longest return a run holds)
        no_return |= ~invalid & (ranges > sensor.max_range_m)
    ranges[no_return | invalid] = np.nan
    directions = np.einsum("sij,bj->sbi", poses[:, :3, :3], sensor.beam_axes())
    return SimulatedScans(poses[:, :3, 3].copy(), directions, ranges, no_return, invalid)
