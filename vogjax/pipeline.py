"""Batch reprocessing: a recorded run -> submaps -> SLAM -> the loop-closure-consistent global map.

    result = vj.pipeline.run("run.h5", vj.pipeline.PipelineConfig())

Per batch of scans the main loop:
1. cuts the stream into submaps (a fixed number of scans, or Sodhi et al.'s Eq. 2 bound),
2. integrates each scan into the current submap in its base-pose frame (navigation poses),
3. for each finished submap: adds its pose-graph node, detects loop closures against earlier
   submaps, updates iSAM2, moves the virtual map's submaps, re-applies the moved and uncertain
   ones in the global map (Algorithm 1) and adds the new one,
4. also builds the standard single map from navigation poses (the no-SLAM baseline).
"""

from __future__ import annotations

import dataclasses
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
from tqdm import tqdm

from vogjax.config import MapConfig, NavNoise
from vogjax.geometry import inverse, pose_deltas
from vogjax.globalmap import GlobalMap
from vogjax.io.dataset import Dataset
from vogjax.slam import LoopClosure, LoopClosureConfig, LoopClosureDetector, PoseGraph, Rejection
from vogjax.submaps import VogMap
from vogjax.voxelmap import VoxelMap


@dataclasses.dataclass(frozen=True)
class PipelineConfig:
    """scans_per_submap: cut a submap every this many scans (100 in Ho, 200 in Sodhi), or
    None to cut by Eq. 2: when the x, y or yaw variance accumulated since its base pose would
    exceed max_xy_variance_m2 / max_yaw_variance_rad2.
    eps_*: Algorithm 1's thresholds (GlobalMap.update_poses).
    batch_scans: scans read and integrated per step.
    """

    map: MapConfig = MapConfig()
    nav_noise: NavNoise = NavNoise()
    loop_closure: LoopClosureConfig = LoopClosureConfig()
    scans_per_submap: int | None = 100
    max_xy_variance_m2: float = 0.0276  # 20 s of the paper's drift
    max_yaw_variance_rad2: float = 2e-6
    eps_rot: float = 1e-2
    eps_trans: float = 2e-3
    eps_cov: float | str = "auto"
    batch_scans: int = 200
    standard_map: bool = True

    def __post_init__(self):
        if self.scans_per_submap is not None and not (isinstance(self.scans_per_submap, int)
                                                      and self.scans_per_submap >= 2):
            raise ValueError(f"scans_per_submap must be an integer >= 2 or None, got {self.scans_per_submap!r}")
        if not (isinstance(self.batch_scans, int) and self.batch_scans >= 1):
            raise ValueError(f"batch_scans must be a positive integer, got {self.batch_scans!r}")
        if not (self.max_xy_variance_m2 > 0 and self.max_yaw_variance_rad2 > 0):
            raise ValueError("max_xy_variance_m2 and max_yaw_variance_rad2 must be positive")
        for name in ("eps_rot", "eps_trans"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0 <= value < float("inf")):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if self.eps_cov != "auto" and not (isinstance(self.eps_cov, (int, float)) and 0 <= self.eps_cov < float("inf")):
            raise ValueError(f"eps_cov must be 'auto' or a finite number >= 0, got {self.eps_cov!r}")


@dataclasses.dataclass
class Result:
    """What a run produced. `navigation`, `optimized`, `truth`: submap base poses (N,4,4);
    `scan_navigation`, `scan_truth`: every scan's pose (S,4,4); `scan_poses("optimized")`
    carries each scan along with its submap."""

    config: PipelineConfig
    global_map: GlobalMap
    vog: VogMap
    standard_map: VoxelMap | None
    navigation: np.ndarray
    optimized: np.ndarray
    truth: np.ndarray | None
    submap_first_scan: np.ndarray  # (N,) first scan of each submap
    loop_closures: list[LoopClosure]
    rejected: list[Rejection]
    timings: dict  # step name -> list of seconds, one per submap (or per batch)
    scans: int
    metadata: dict
    scan_navigation: np.ndarray
    scan_truth: np.ndarray | None

    @property
    def metrics(self) -> dict:
        """What needs no ground-truth map: base-pose RMS error of navigation and optimised poses
        (m; when the run has true poses) and loop closures by verdict."""
        errors = {}
        if self.truth is not None and len(self.truth) == len(self.navigation):
            for name in ("navigation", "optimized"):
                offsets = getattr(self, name)[:, :3, 3] - self.truth[:, :3, 3]
                errors[name] = float(np.sqrt(np.mean(np.sum(offsets**2, axis=1))))
        rejected = {}
        for r in self.rejected:
            rejected[r.reason] = rejected.get(r.reason, 0) + 1
        return {"trajectory_rmse_m": errors,
                "loop_closures": {"accepted": len(self.loop_closures), "rejected": len(self.rejected),
                                  "rejected_by_reason": rejected}}

    def scan_poses(self, which: str) -> np.ndarray:
        """(S,4,4) per-scan poses: "navigation", "truth" or "optimized" (each scan moved rigidly
        with its submap's base pose, as the maps place it)."""
        if which == "navigation":
            return self.scan_navigation
        if which == "truth":
            return self.scan_truth
        if which != "optimized":
            raise ValueError(f"which must be 'navigation', 'truth' or 'optimized', got {which!r}")
        submap = np.searchsorted(self.submap_first_scan, np.arange(self.scans), side="right") - 1
        correction = self.optimized @ np.linalg.inv(self.navigation)
        return correction[submap] @ self.scan_navigation


class _SubmapCutter:
    """Decides where submaps end: a fixed number of scans, or the Eq. 2 covariance bound."""

    def __init__(self, config: PipelineConfig):
        self.config = config
        noise = config.nav_noise
        # Eq. 2: the variances grow linearly in time, so the bound is a longest duration.
        self.max_duration_s = min(config.max_xy_variance_m2 / max(noise.sigma2_x, noise.sigma2_y),
                                  config.max_yaw_variance_rad2 / noise.sigma2_yaw)

    def ends_before(self, scans_in_submap: int, elapsed_s: float) -> bool:
        """Should a submap that holds `scans_in_submap` scans over `elapsed_s` end before the next?"""
        if self.config.scans_per_submap is not None:
            return scans_in_submap >= self.config.scans_per_submap
        return elapsed_s > self.max_duration_s * (1 + 1e-9)  # round-off in time stamps is not drift


def run(dataset, config: PipelineConfig | None = None, progress: bool = True) -> Result:
    """Reprocess a run (a path or an open vogjax.io.dataset.Dataset) into maps."""
    config = config or PipelineConfig()
    own = not isinstance(dataset, Dataset)
    ds = Dataset(dataset) if own else dataset
    try:
        if len(ds) == 0:
            raise ValueError(f"dataset {str(ds.path)!r} holds no scans")
        return _Pipeline(config, ds).run(progress)
    finally:
        if own:
            ds.close()


class _Pipeline:
    def __init__(self, config: PipelineConfig, ds: Dataset):
        self.config, self.ds = config, ds
        self.vog = VogMap(config.map)
        self.global_map = GlobalMap(config.map)
        self.standard = VoxelMap(config.map) if config.standard_map else None
        self.graph: PoseGraph | None = None
        self.detector = LoopClosureDetector(config.nav_noise, config.loop_closure)
        self.cutter = _SubmapCutter(config)
        self.timings = defaultdict(list)
        self.nav_bases, self.truth_bases, self.base_times, self.first_scans = [], [], [], []
        self.accepted, self.rejected = [], []
        self.scans_in_submap = 0
        self.scan_nav, self.scan_truth = [], []

    def run(self, progress: bool) -> Result:
        cfg, ds = self.config, self.ds
        with tqdm(total=len(ds), unit="scan", desc="mapping", disable=not progress) as bar:
            for batch in ds.batches(cfg.batch_scans):
                self._process(batch)
                bar.update(len(batch))
        if self.scans_in_submap:
            self._finish_submap()
        return Result(cfg, self.global_map, self.vog, self.standard, np.array(self.nav_bases),
                      self.vog.poses(), np.array(self.truth_bases), np.array(self.first_scans),
                      self.accepted, self.rejected, dict(self.timings), len(ds), ds.metadata,
                      np.concatenate(self.scan_nav), np.concatenate(self.scan_truth))

    def _process(self, batch) -> None:
        cfg = self.config
        self.scan_nav.append(batch.pose_nav)
        self.scan_truth.append(batch.pose_truth)
        # 1. the standard map: every scan at its navigation pose, in one batch
        origins, endpoints = batch.world(batch.pose_nav, cfg.map.max_range)
        if self.standard is not None:
            start = time.perf_counter()
            self.standard.integrate_scans(origins, endpoints.reshape(-1, 3),
                                          np.repeat(np.arange(len(batch)), endpoints.shape[1]))
            self.timings["standard_map"].append(time.perf_counter() - start)
        # 2. cut into submaps; integrate each run of scans in its submap's frame
        first = 0
        while first < len(batch):
            if self.scans_in_submap == 0:
                self._start_submap(batch, first)
            elapsed = batch.time_s[first:] - self.base_times[-1]
            room = len(batch) - first
            for n in range(room):
                if self.cutter.ends_before(self.scans_in_submap + n, float(elapsed[n])):
                    room = n
                    break
            if room:
                self._integrate(batch, first, first + room)
                self.scans_in_submap += room
                first += room
            if first < len(batch):  # the submap is full
                self._finish_submap()

    def _start_submap(self, batch, row: int) -> None:
        base = batch.pose_nav[row]
        initial = base if self.graph is None else self._predicted_pose(base)
        self.vog.add_submap(initial)
        self.nav_bases.append(base)
        self.truth_bases.append(batch.pose_truth[row])
        self.base_times.append(float(batch.time_s[row]))
        self.first_scans.append(batch.first + row)

    def _predicted_pose(self, base_nav: np.ndarray) -> np.ndarray:
        """Where the optimised previous submap puts a new base pose (navigation's relative motion)."""
        previous = self.graph.num_submaps - 1
        return self.graph.poses()[previous] @ inverse(self.nav_bases[previous]) @ base_nav

    def _integrate(self, batch, lo: int, hi: int) -> None:
        start = time.perf_counter()
        part = batch.rows(lo, hi)
        origins, endpoints = part.world(inverse(self.nav_bases[-1]) @ part.pose_nav, self.config.map.max_range)
        self.vog.submap(len(self.nav_bases) - 1).integrate_scans(
            origins, endpoints.reshape(-1, 3), np.repeat(np.arange(hi - lo), endpoints.shape[1]))
        self.timings["integration"].append(time.perf_counter() - start)

    def _finish_submap(self) -> None:
        cfg = self.config
        k = len(self.nav_bases) - 1
        self.scans_in_submap = 0
        # a. pose-graph node with its xyh and zpr factors
        start = time.perf_counter()
        if self.graph is None:
            self.graph = PoseGraph(cfg.nav_noise, prior_pose=self.nav_bases[0])
            self.graph.add_submap(self.nav_bases[0])
        else:
            self.graph.add_submap(self.nav_bases[k], self.base_times[k] - self.base_times[k - 1])
        poses = self.graph.update()
        self.timings["isam2"].append(time.perf_counter() - start)
        # b. loop closures against earlier submaps
        start = time.perf_counter()
        submaps = [self.vog.submap(i) for i in range(k + 1)]
        accepted, rejected = self.detector.detect(
            k, [s.occupied_points() for s in submaps], [s.bounds() for s in submaps], poses,
            np.array(self.nav_bases), np.array(self.base_times))
        self.accepted += accepted
        self.rejected += rejected
        self.timings["loop_closure"].append(time.perf_counter() - start)
        for phase, seconds in self.detector.seconds.items():  # its parts
            self.timings[phase].append(seconds)
        # c. iSAM2 with the new constraints
        start = time.perf_counter()
        for closure in accepted:
            self.graph.add_loop_closure(closure.i, closure.k, closure.T_i_k, closure.covariance, closure.basis)
        before = self.vog.poses()
        poses = self.graph.update()
        # marginals of the submaps that moved, of the first ten (they set eps_cov) and the new one
        angle, shift = pose_deltas(before, poses)
        wanted = sorted(set(np.flatnonzero((angle > cfg.eps_rot) | (shift > cfg.eps_trans)).tolist())
                        | set(range(min(10, k + 1))) | {k})
        marginals = np.zeros((k + 1, 6, 6))
        marginals[wanted] = self.graph.marginals(wanted)
        self.timings["isam2"][-1] += time.perf_counter() - start
        # d. move the submaps (the virtual map's whole update)
        start = time.perf_counter()
        self.vog.set_poses(np.arange(k + 1), poses)
        self.timings["virtual_update"].append(time.perf_counter() - start)
        # e. undo/redo what moved in the global map, then add the new submap
        start = time.perf_counter()
        report = self.global_map.update_poses(self.vog, marginals, cfg.eps_rot, cfg.eps_trans, cfg.eps_cov)
        self.timings["undo_redo"].append(time.perf_counter() - start)
        self.timings["reapplied"].append(len(report.reapplied))
        start = time.perf_counter()
        self.global_map.add(self.vog, [k], marginals)
        self.timings["add"].append(time.perf_counter() - start)


def save_trajectories(result: Result, path) -> None:
    """CSV: per submap its first scan and x, y, z, yaw of the navigation, optimised and true base poses."""
    from vogjax.slam.factors import yaw_pitch_roll

    columns = ["submap", "first_scan"]
    rows = [np.arange(len(result.navigation)), result.submap_first_scan]
    for name in ("navigation", "optimized", "truth"):
        poses = getattr(result, name)
        if poses is None or len(poses) != len(result.navigation):
            continue
        columns += [f"{name}_{c}" for c in ("x", "y", "z", "yaw")]
        rows += [poses[:, 0, 3], poses[:, 1, 3], poses[:, 2, 3],
                 np.array([yaw_pitch_roll(p[:3, :3])[0] for p in poses])]
    np.savetxt(Path(path), np.stack(rows, axis=1), delimiter=",", header=",".join(columns), comments="",
               fmt=["%d", "%d"] + ["%.6f"] * (len(columns) - 2))
