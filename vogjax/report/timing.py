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
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from vogjax.pipeline.probes import planner_rays

if TYPE_CHECKING:
    from vogjax.pipeline import Result

__all__ = ["TimingCurves", "cumulative_average", "curves", "planner_rays"]


@dataclasses.dataclass(frozen=True)
class TimingCurves:
    """The timing curves of one run (Sodhi et al., Figs. 8 and 9).

    Per submap count n = 1..N the cumulative average update time per submap of each way to keep
    the map current (Fig. 9); per timing probe (Q of them) the full-merge and planner-query times
    (Fig. 8).

    Attributes
    ----------
    online_s : (N,) ndarray of float64
        The online global map: undo/redo of what moved plus adding the new submap, seconds per
        submap, cumulative average.
    virtual_s : (N,) ndarray of float64
        The virtual map: setting the poses, seconds per submap, cumulative average.
    full_merge_s : (N,) ndarray of float64
        The baseline: adding the new submap, plus a full re-merge at each loop closure
        (interpolated between the probes), seconds per submap, cumulative average.
    reapplied : (N,) ndarray of int64
        Submaps the online map re-applied at each new submap.
    sampled_submaps : (Q,) ndarray of int
        Submap count at each probe.
    merge_s : (Q,) ndarray of float
        Time of a full merge of every submap so far, seconds.
    query_global_s : (Q,) ndarray of float
        Time of one planner query of `rays` rays on the global map, seconds.
    query_virtual_s : (Q,) ndarray of float
        The same query on the virtual map, seconds.
    rays : int
        Rays per planner query (`TimingConfig.rays`).
    """

    online_s: npt.NDArray[np.float64]
    virtual_s: npt.NDArray[np.float64]
    full_merge_s: npt.NDArray[np.float64]
    reapplied: npt.NDArray[np.int64]
    sampled_submaps: npt.NDArray[np.int_]
    merge_s: npt.NDArray[np.float64]
    query_global_s: npt.NDArray[np.float64]
    query_virtual_s: npt.NDArray[np.float64]
    rays: int

    def to_dict(self) -> dict:
        """The curves as plain lists, for JSON.

        Returns
        -------
        dict
            Every field by name, arrays as lists.
        """
        return {
            f.name: (v.tolist() if isinstance(v := getattr(self, f.name), np.ndarray) else v)
            for f in dataclasses.fields(self)
        }

    def fig9(self) -> dict:
        """Fig. 9's data, for JSON.

        Returns
        -------
        dict
            ``submaps`` (1..N), the three cumulative averages ``online_s``, ``virtual_s``,
            ``full_merge_s`` (seconds) and ``reapplied`` submaps per new submap, as lists.
        """
        return {
            "submaps": list(range(1, len(self.online_s) + 1)),
            "online_s": self.online_s.tolist(),
            "virtual_s": self.virtual_s.tolist(),
            "full_merge_s": self.full_merge_s.tolist(),
            "reapplied": self.reapplied.tolist(),
        }


def cumulative_average(values: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Running mean: element n is the mean of the first n + 1 values.

    Parameters
    ----------
    values : (N,) array_like of float
        The values.

    Returns
    -------
    (N,) ndarray of float64
        Their cumulative averages.
    """
    values = np.asarray(values, dtype=np.float64)
    return np.cumsum(values) / np.arange(1, len(values) + 1)


def curves(result: Result) -> TimingCurves | None:
    """The timing curves of a pipeline run, from what it measured.

    Parameters
    ----------
    result : Result
        A pipeline run (`vj.pipeline.run`).

    Returns
    -------
    TimingCurves or None
        The curves; None when the run took no timing probes (``TimingConfig.every_submaps`` 0,
        or no submap).
    """
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
