"""Simulated profiling sonar: ranges by ray casting against the scene mesh in Warp."""

from __future__ import annotations

import dataclasses

import numpy as np
import warp as wp

from vogjax import _warp
from vogjax.config import SonarConfig
from vogjax.kernels import sonar as sonar_kernels


@dataclasses.dataclass(frozen=True)
class SonarScans:
    """S scans of B beams, world frame: origins (S,3); directions (S,B,3) unit vectors;
    ranges (S,B) metres (NaN where no return); no_return (S,B) bool."""

    origins: np.ndarray
    directions: np.ndarray
    ranges: np.ndarray
    no_return: np.ndarray


def beam_directions(config: SonarConfig) -> np.ndarray:
    """(B, U, 3) unit directions in the vehicle frame: B beams in the x-z plane, each with U
    sub-rays spread across the elevation aperture."""
    elevation = np.deg2rad(config.tilt_deg + np.linspace(-config.fov_deg / 2, config.fov_deg / 2, config.beams))
    if config.subrays == 1:
        across = np.zeros(1)
    else:
        across = np.deg2rad(np.linspace(-config.aperture_deg / 2, config.aperture_deg / 2, config.subrays))
    e, a = np.meshgrid(elevation, across, indexing="ij")
    return np.stack([np.cos(e) * np.cos(a), np.sin(a), np.sin(e) * np.cos(a)], axis=-1)


def scan(mesh: wp.Mesh, T_world_sonar: np.ndarray, config: SonarConfig,
         rng: np.random.Generator | None = None) -> SonarScans:
    """Scans from sonar poses (S,4,4): one per pose, all in one launch."""
    _warp.init()
    poses = np.asarray(T_world_sonar, dtype=np.float64).reshape(-1, 4, 4)
    count = len(poses)
    local = beam_directions(config)
    ranges = wp.empty((count, config.beams), dtype=float, device="cpu")
    if count:
        wp.launch(sonar_kernels.cast_sonar_beams, dim=(count, config.beams),
                  inputs=[mesh.id, wp.array(poses[:, :3, 3], dtype=wp.vec3, device="cpu"),
                          wp.array(poses[:, :3, :3], dtype=wp.mat33, device="cpu"),
                          wp.array(local, dtype=wp.vec3, device="cpu"), float(config.min_range_m),
                          float(config.max_range_m)],
                  outputs=[ranges], device="cpu")
    ranges = ranges.numpy().astype(np.float64)
    no_return = ranges < 0
    if config.range_noise_m > 0:
        rng = rng or np.random.default_rng()
        ranges = ranges + rng.normal(0.0, config.range_noise_m, ranges.shape)
    ranges[no_return] = np.nan
    centre = local[:, local.shape[1] // 2]  # the beam's central sub-ray
    directions = np.einsum("sij,bj->sbi", poses[:, :3, :3], centre)
    return SonarScans(poses[:, :3, 3].copy(), directions, ranges, no_return)
