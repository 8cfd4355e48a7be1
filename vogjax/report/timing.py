"""Timing curves of a pipeline run (Sodhi et al., Figs. 8 and 9), read from what the run measured.

Fig. 9: map update time per submap, as a cumulative average, for three ways to keep a map of a
SLAM run current: the paper's baseline (add each new submap, and re-merge every submap from
scratch whenever a loop closure arrives), the virtual map (setting the poses is its whole
update) and the online global map (undo/redo of what moved, then adding the new submap).
Fig. 8: one planner query against the global map and the virtual map as the submaps grow.
The baseline's re-merge time comes from the run's probes (`vogjax.pipeline.probes`), linear in
the submaps between them.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from vogjax.pipeline.probes import planner_rays

__all__ = ["TimingCurves", "cumulative_average", "curves", "planner_rays"]


@dataclasses.dataclass(frozen=True)
class TimingCurves:
    """Per submap count n = 1..N (N,): cumulative average update time per submap of the online
    map, the virtual map and the full-merge baseline, and the submaps re-applied per new
    submap. Per probe (Q,): the submap count, its full merge time and planner-query times."""

    online_s: np.ndarray
    virtual_s: np.ndarray
    full_merge_s: np.ndarray
    reapplied: np.ndarray
    sampled_submaps: np.ndarray
    merge_s: np.ndarray
    query_global_s: np.ndarray
    query_virtual_s: np.ndarray
    rays: int

    def to_dict(self) -> dict:
        return {
            f.name: (v.tolist() if isinstance(v := getattr(self, f.name), np.ndarray) else v)
            for f in dataclasses.fields(self)
        }

    def fig9(self) -> dict:
        """Fig. 9's data: submap counts and the three cumulative averages (s), and re-applied
        submaps per new submap."""
        return {
            "submaps": list(range(1, len(self.online_s) + 1)),
            "online_s": self.online_s.tolist(),
            "virtual_s": self.virtual_s.tolist(),
            "full_merge_s": self.full_merge_s.tolist(),
            "reapplied": self.reapplied.tolist(),
        }


def cumulative_average(values: np.ndarray) -> np.ndarray:
    values = np.asarray(values, dtype=np.float64)
    return np.cumsum(values) / np.arange(1, len(values) + 1)


def curves(result) -> TimingCurves | None:
    """The curves of a pipeline Result; None when the run took no timing probes."""
    if not result.probes:
        return None
    timings = result.timings
    n = len(result.submaps)
    sampled = np.array([p["submaps"] for p in result.probes])
    merge_s = np.array([p["full_merge_s"] for p in result.probes])
    # a full re-merge grows linearly with the submaps it holds (and costs nothing at zero)
    merge = np.interp(np.arange(1, n + 1), np.r_[0, sampled], np.r_[0.0, merge_s])
    add = np.asarray(timings["add"], dtype=np.float64)
    baseline = add + np.where(np.asarray(timings["closures"]) > 0, merge, 0.0)
    online = np.asarray(timings["undo_redo"], dtype=np.float64) + add
    return TimingCurves(
        cumulative_average(online),
        cumulative_average(timings["virtual_update"]),
        cumulative_average(baseline),
        np.asarray(timings["reapplied"], dtype=np.int64),
        sampled,
        merge_s,
        np.array([p["query_global_s"] for p in result.probes]),
        np.array([p["query_virtual_s"] for p in result.probes]),
        result.config.timing.rays,
    )
