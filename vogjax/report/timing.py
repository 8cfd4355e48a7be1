"""Timing curves of a pipeline run (Sodhi et al., Figs. 8 and 9).

Map update time per submap, as a cumulative average, for three ways to keep a map of a SLAM
run current: a full re-merge of every submap after each update, the virtual map (setting the
poses is its whole update), and the online global map (undo/redo of what moved, then adding
the new submap). And the time of one planner query of 100k rays against the global map and
the virtual map as the number of submaps grows.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from tqdm import tqdm

from vogjax.maps.globalmap import GlobalMap


@dataclasses.dataclass(frozen=True)
class TimingCurves:
    """Per submap count n = 1..N (N,): cumulative average update time per submap of each map.
    Per sampled count (Q,): full merge time and 100k-ray query times."""

    online_s: np.ndarray
    virtual_s: np.ndarray
    full_merge_s: np.ndarray
    sampled_submaps: np.ndarray
    merge_s: np.ndarray
    query_global_s: np.ndarray
    query_virtual_s: np.ndarray
    rays: int

    def to_dict(self) -> dict:
        return {f.name: (v.tolist() if isinstance(v := getattr(self, f.name), np.ndarray) else v)
                for f in dataclasses.fields(self)}


def cumulative_average(values: np.ndarray) -> np.ndarray:
    values = np.asarray(values, dtype=np.float64)
    return np.cumsum(values) / np.arange(1, len(values) + 1)


def planner_rays(block_map, count: int, rng=0) -> tuple[np.ndarray, np.ndarray]:
    """`count` planner rays in a VoxelMap or GlobalMap: origins at observed free voxel centres,
    random unit directions. rng: a seed or a numpy Generator."""
    rng = np.random.default_rng(rng)
    centres, log_odds = block_map.voxels()
    free = centres[log_odds <= block_map.config.log_free]
    if len(free) == 0:
        free = centres
    origins = free[rng.integers(0, len(free), count)].astype(np.float64)
    directions = rng.normal(size=origins.shape)
    return origins, directions / np.linalg.norm(directions, axis=1, keepdims=True)


def measure(result, rays: int = 100_000, samples: int = 6, ray_length_m: float = 4.0,
            progress: bool = True) -> TimingCurves:
    """Timing curves of a pipeline Result: full merges and queries at `samples` submap counts
    (the submaps 0..n-1 at their final poses), the online and virtual update times as recorded."""
    vog = result.vog
    total = vog.num_submaps
    counts = np.unique(np.linspace(1, total, min(samples, total)).round().astype(int))
    origins, directions = planner_rays(result.global_map, rays)
    merge_s, query_global, query_virtual = [], [], []
    for n in tqdm(counts, desc="timing merges and queries", unit="size", disable=not progress):
        view = vog.view(np.arange(n))
        gmap = GlobalMap(vog.config, vog.device)
        start = time.perf_counter()
        gmap.merge(view)
        merge_s.append(time.perf_counter() - start)
        for m, times in ((gmap, query_global), (view, query_virtual)):
            m.raycast(origins[:16], directions[:16], ray_length_m)  # kernels compiled and loaded
            start = time.perf_counter()
            m.raycast(origins, directions, ray_length_m)
            times.append(time.perf_counter() - start)
    # A full re-merge grows linearly with the submaps it holds: interpolate between the samples.
    full = np.interp(np.arange(1, total + 1), counts, merge_s)
    online = np.asarray(result.timings["undo_redo"]) + np.asarray(result.timings["add"])
    return TimingCurves(cumulative_average(online), cumulative_average(result.timings["virtual_update"]),
                        cumulative_average(full), counts, np.array(merge_s), np.array(query_global),
                        np.array(query_virtual), rays)
