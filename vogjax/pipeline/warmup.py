"""Kernel warm-up: every Warp kernel a run launches, compiled (or loaded from the cache) on a
few synthetic scans before anything is timed, so reported timings are the pipeline's own and
not one-off compilation (a cold first run compiles for a minute)."""

from __future__ import annotations

import time

import numpy as np
import warp as wp

from vogjax.config import PipelineConfig
from vogjax.geometry import pose_from_xyz_yaw
from vogjax.maps import GlobalMap, VogMap, VoxelMap


def warm_up(config: PipelineConfig | None = None, device: str | wp.Device | None = None) -> float:
    """Launch integration, merges, undo/redo and every query once on tiny maps, so kernel
    compilation stays out of the timings.

    Parameters
    ----------
    config : PipelineConfig or None, optional
        The settings whose kernels to compile (default: the papers').
    device : str or warp.Device or None, optional
        The Warp device (None: the default).

    Returns
    -------
    float
        The seconds it took.
    """
    config = config or PipelineConfig()
    start = time.perf_counter()
    rng = np.random.default_rng(0)
    cfg = config.map
    origins = np.zeros((2, 3))
    points = rng.normal(size=(64, 3)) * 2.0
    scan_index = np.repeat(np.arange(2), 32)
    standard = VoxelMap(cfg, device)
    standard.integrate_scans(origins, points, scan_index)
    vog = VogMap(cfg, device)
    for x in (0.0, 0.3):
        i = vog.add_submap(pose_from_xyz_yaw(x, 0.0, 0.0, 0.1))
        vog.submap(i).integrate_scans(origins, points, scan_index)
    online = GlobalMap(cfg, device)
    online.add(vog, [0, 1])
    vog.set_poses([1], pose_from_xyz_yaw(0.5, 0.1, 0.0, 0.2)[None])
    online.update_poses(vog)
    GlobalMap(cfg, device).merge(vog)
    directions = rng.normal(size=(8, 3))
    for m in (standard, online, vog):
        m.raycast(np.zeros((8, 3)), directions, 4.0)
        m.state(points[:8])
        m.line_query(np.zeros((2, 3)), points[:2])
    return time.perf_counter() - start
