"""Timing probes taken during a run (Sodhi et al., Figs. 8 and 9), by the mapper itself.

A probe times what a full-merge baseline redoes at a loop closure (merging every submap so far
from scratch) and one planner query (`planner_rays`) against the online global map and against
the virtual map. The report turns the probes and the per-submap update times into the figures.
"""

from __future__ import annotations

import time

import numpy as np
import warp as wp

from vogjax.maps import GlobalMap


def planner_rays(block_map, count: int, rng=0) -> tuple[np.ndarray, np.ndarray]:
    """`count` planner rays in a VoxelMap or GlobalMap: origins at observed free voxel centres,
    random unit directions. rng: a seed or a numpy Generator."""
    rng = np.random.default_rng(rng)
    centres, log_odds = block_map.voxels()
    free = centres[log_odds <= block_map.config.log_free]
    if len(free) == 0:
        free = centres
    if len(free) == 0:
        free = np.zeros((1, 3))
    origins = free[rng.integers(0, len(free), count)].astype(np.float64)
    directions = rng.normal(size=origins.shape)
    return origins, directions / np.linalg.norm(directions, axis=1, keepdims=True)


def probe(mapper) -> dict:
    """Time a full merge and a planner query on the global and the virtual map, now."""
    cfg = mapper.config
    merged = GlobalMap(cfg.map, mapper.global_map.device)
    start = time.perf_counter()
    merged.merge(mapper.vog)
    wp.synchronize()
    merge_s = time.perf_counter() - start
    origins, directions = planner_rays(mapper.global_map, cfg.timing.rays, rng=mapper.num_submaps)
    queries = {}
    for name, m in (("global", mapper.global_map), ("virtual", mapper.vog)):
        m.raycast(origins[:16], directions[:16], cfg.timing.ray_length_m)  # kernels loaded
        start = time.perf_counter()
        m.raycast(origins, directions, cfg.timing.ray_length_m)
        queries[name] = time.perf_counter() - start
    return {
        "submaps": mapper.num_submaps,
        "full_merge_s": merge_s,
        "query_global_s": queries["global"],
        "query_virtual_s": queries["virtual"],
    }
