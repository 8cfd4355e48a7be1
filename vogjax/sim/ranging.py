"""Simulated range scans: any RangeSensor's beams cast against the scene mesh in Warp."""

from __future__ import annotations

import dataclasses

import numpy as np
import warp as wp

from vogjax import devices
from vogjax.kernels import ranging
from vogjax.sensors import as_sensor


@dataclasses.dataclass(frozen=True)
class SimulatedScans:
    """S scans of B beams, world frame: origins (S,3); directions (S,B,3) unit vectors;
    ranges (S,B) metres (NaN where no return); no_return (S,B) bool."""

    origins: np.ndarray
    directions: np.ndarray
    ranges: np.ndarray
    no_return: np.ndarray


def scan(mesh: wp.Mesh, T_world_sensor: np.ndarray, sensor, rng: np.random.Generator | None = None) -> SimulatedScans:
    """Scans from sensor poses (S,4,4), one per pose, all in one launch. `sensor`: a
    vogjax.sensors.RangeSensor (or a SonarConfig, for the papers' profiling sonar)."""
    devices.init()
    sensor = as_sensor(sensor)
    poses = np.asarray(T_world_sensor, dtype=np.float64).reshape(-1, 4, 4)
    count = len(poses)
    local = sensor.beam_directions()
    ranges = wp.empty((count, sensor.beams), dtype=float, device="cpu")
    if count:
        wp.launch(ranging.cast_sensor_beams, dim=(count, sensor.beams),
                  inputs=[mesh.id, wp.array(poses[:, :3, 3], dtype=wp.vec3, device="cpu"),
                          wp.array(poses[:, :3, :3], dtype=wp.mat33, device="cpu"),
                          wp.array(local, dtype=wp.vec3, device="cpu"), float(sensor.min_range_m),
                          float(sensor.max_range_m)],
                  outputs=[ranges], device="cpu")
    ranges = ranges.numpy().astype(np.float64)
    no_return = ranges < 0
    if sensor.range_noise_m > 0:
        rng = rng or np.random.default_rng()
        ranges = ranges + rng.normal(0.0, sensor.range_noise_m, ranges.shape)
    ranges[no_return] = np.nan
    centre = local[:, local.shape[1] // 2]  # the beam's central sub-ray
    directions = np.einsum("sij,bj->sbi", poses[:, :3, :3], centre)
    return SimulatedScans(poses[:, :3, 3].copy(), directions, ranges, no_return)
