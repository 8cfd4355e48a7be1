"""The mapper: scans in, submaps, SLAM and the loop-closure-consistent global map out.

Feed it scans batch by batch (`add`), from a recorded run or live from a vehicle, and ask for
the `result()` at any time. Per batch it:
1. integrates the batch into the standard map at the navigation poses (the no-SLAM baseline),
2. cuts the stream into submaps, holding each submap's scans until it is complete.
Per finished submap it:
a. integrates the submap's scans in the frame of its middle scan (its base pose),
b. adds the pose-graph node with its xyh and zpr factors and updates iSAM2,
c. looks for loop closures with earlier submaps (correlative search, then ICP),
d. adds the accepted closures, updates iSAM2 and computes the marginals it needs,
e. moves the virtual map's submaps (setting poses is its whole update),
f. re-applies the moved and uncertain submaps in the global map (Algorithm 1), adds the new one,
g. every so many submaps, times a full merge and planner queries (`probes.py`).
When the run has ground truth it also builds each submap from the true poses (`truth_vog`):
the map this sensor would give with perfect SLAM, the ceiling the report compares against.

Why the middle scan: a submap's scans are placed by navigation relative to its base pose, so
each submap is bent by the drift accumulated inside it, and a loop closure (aligning two clouds)
measures the bent clouds' best overlap, not the true relation of the base poses. Relative to
the first scan the mean misplacement of a submap's cloud grows like the drift over the whole
submap; relative to the middle scan, like the drift over half of it on either side: on a
200-scan propeller survey the closures' bias fell from 0.21 m to about half. The papers use
the first scan; nothing else changes (the graph, the factors, the maps are the same), and a
submap reaches the maps and the graph only once it is complete, as before.
"""

from __future__ import annotations

import dataclasses
import time
from collections import defaultdict

import numpy as np

from vogjax import sensors
from vogjax.config import CrmConfig, PipelineConfig
from vogjax.geometry import inverse
from vogjax.io.dataset import MAX_BEAMS, ScanBatch, check_scans
from vogjax.maps import ConfidenceMap, GlobalMap, VogMap, VoxelMap
from vogjax.pipeline.cutter import SubmapCutter
from vogjax.pipeline.probes import probe
from vogjax.pipeline.result import Result, SubmapRecord
from vogjax.sensors import mapped_beams
from vogjax.slam import LoopClosureDetector, PoseGraph


class Mapper:
    def __init__(self, config: PipelineConfig | None = None, metadata: dict | None = None):
        self.config = config = config or PipelineConfig()
        if not isinstance(config, PipelineConfig):
            raise ValueError(f"config must be a PipelineConfig, got {type(config).__name__}")
        self.metadata = dict(metadata or {})
        # a beam without a return clears free space as far as the sensor reaches (and the map allows)
        self.reach_m = min(config.map.max_range, sensors.from_metadata(self.metadata).max_range_m)
        self.vog = VogMap(config.map)
        self.truth_vog = VogMap(config.map)  # the same submaps from true poses, when the run has them
        self.global_map = GlobalMap(config.map)
        self.standard_map = VoxelMap(config.map) if config.standard_map else None
        self.confidence_map = self._confidence_map() if config.confidence_map else None
        self.graph: PoseGraph | None = None
        # on a GPU the front end's searches run beside the maps; on the CPU the FFTs and trees win
        self.detector = LoopClosureDetector(
            config.nav_noise, config.loop_closure, self.global_map.device if self.global_map.device.is_cuda else None
        )
        self.cutter = SubmapCutter(config)
        self.timings = defaultdict(list)
        self.submaps: list[SubmapRecord] = []
        self.accepted, self.rejected = [], []
        self.probes: list[dict] = []
        self.clouds: list[np.ndarray] = []  # per submap: its returns, one mean point per voxel
        self.scans = 0
        self._pending: list[ScanBatch] = []  # the scans of the submap being filled
        self._scan_time, self._scan_nav, self._scan_truth = [], [], []
        self._beams = 0  # per scan, set by the first batch

    @property
    def num_submaps(self) -> int:
        """Finished submaps: those in the pose graph and the global map."""
        return len(self.submaps)

    def add(self, batch: ScanBatch) -> None:
        """Integrate a batch of consecutive scans; finish every submap it completes.

        The batch is checked as a run file's scans are (finite, rigid poses; times increasing
        from the last scan added; the beam count and ground truth of the first batch) before
        anything changes."""
        self._check(batch)
        if not len(batch):
            return
        self._scan_time.append(batch.time_s)
        self._scan_nav.append(batch.pose_nav)
        self._scan_truth.append(batch.pose_truth)
        # 1. the maps without SLAM: every scan at its navigation pose, in one batch (an invalid
        # beam, its surface within the blind distance, clears nothing: it is left out)
        beams = batch.beams(batch.pose_nav, self.reach_m)
        for name, whole_map in (("standard_map", self.standard_map), ("confidence_map", self.confidence_map)):
            if whole_map is not None:
                start = time.perf_counter()
                whole_map.integrate_scans(*beams)
                self.timings[name].append(time.perf_counter() - start)
        # 2. cut into submaps, holding each one's scans until it is complete
        first = 0
        while first < len(batch):
            held = sum(len(part) for part in self._pending)
            started_s = self._pending[0].time_s[0] if self._pending else batch.time_s[first]
            room = max(self.cutter.room(held, batch.time_s[first:] - started_s), 0 if held else 1)
            if room:
                self._pending.append(batch.rows(first, first + room))
                first += room
            if first < len(batch):  # the submap is full
                self.finish_submap()
        self.scans += len(batch)

    def _check(self, batch) -> None:
        if not isinstance(batch, ScanBatch):
            raise ValueError(f"batch must be a ScanBatch, got {type(batch).__name__}")
        fields = {f.name: getattr(batch, f.name) for f in dataclasses.fields(batch) if f.name != "first"}
        beams = int(np.shape(batch.ranges)[1]) if np.ndim(batch.ranges) == 2 else -1
        if self._scan_time:  # what the first batch set
            if beams != self._beams:
                raise ValueError(f"batch: {beams} beams per scan, but the scans before had {self._beams}")
            truth = self._scan_truth[0] is not None
        else:
            if not 1 <= beams <= MAX_BEAMS:
                raise ValueError(f"batch: ranges must have shape (scans, beams) with 1 to {MAX_BEAMS} beams")
            truth = batch.pose_truth is not None
        after = float(self._scan_time[-1][-1]) if self._scan_time else -np.inf
        check_scans(fields, beams, "batch", after_time_s=after, truth=truth)
        self._beams = beams

    def finish_submap(self) -> None:
        """Close the submap being filled (if any): SLAM and the global map take it in."""
        if not self._pending:
            return
        cfg = self.config
        scans = ScanBatch.concatenate(self._pending)
        self._pending = []
        k = len(self.submaps)
        self._integrate_submap(scans)
        nav_bases = np.array([s.T_world_base_nav for s in self.submaps])
        # a. pose-graph node with its xyh and zpr factors
        start = time.perf_counter()
        if self.graph is None:
            self.graph = PoseGraph(cfg.nav_noise, prior_pose=nav_bases[0])
            self.graph.add_submap(nav_bases[0])
        else:
            self.graph.add_submap(nav_bases[k], self.submaps[k].time_s - self.submaps[k - 1].time_s)
        poses = self.graph.update()
        self.timings["isam2"].append(time.perf_counter() - start)
        # b. loop closures against earlier submaps
        start = time.perf_counter()
        submaps = [self.vog.submap(i) for i in range(k + 1)]
        accepted, rejected = self.detector.detect(
            k, self.clouds, [s.bounds() for s in submaps], poses, nav_bases, np.array([s.time_s for s in self.submaps])
        )
        self.accepted += accepted
        self.rejected += rejected
        self.timings["loop_closure"].append(time.perf_counter() - start)
        for phase, seconds in self.detector.seconds.items():  # its parts
            self.timings[phase].append(seconds)
        # c. iSAM2 with the new constraints
        start = time.perf_counter()
        for closure in accepted:
            self.graph.add_loop_closure(closure.i, closure.k, closure.T_i_k, closure.covariance, closure.basis)
        poses = self.graph.update()
        self.timings["isam2"][-1] += time.perf_counter() - start
        # d. move the submaps (the virtual map's whole update)
        start = time.perf_counter()
        self.vog.set_poses(np.arange(k + 1), poses)
        self.timings["virtual_update"].append(time.perf_counter() - start)
        # marginals of what Algorithm 1 will judge: the submaps it finds moved (S1, however small
        # each step was, measured from the pose the global map holds them at), the first ten
        # (they set eps_cov) and the new one; the rest are not computed (NaN), never zero
        start = time.perf_counter()
        moved = self.global_map.moved_submaps(self.vog, cfg.eps_rot, cfg.eps_trans, cfg.eps_move_m)
        wanted = sorted(set(moved) | set(range(min(10, k + 1))) | {k})
        marginals = np.full((k + 1, 6, 6), np.nan)
        marginals[wanted] = self.graph.marginals(wanted)
        self.timings["isam2"][-1] += time.perf_counter() - start
        # e. undo/redo what moved in the global map, then add the new submap
        start = time.perf_counter()
        report = self.global_map.update_poses(
            self.vog, marginals, cfg.eps_rot, cfg.eps_trans, cfg.eps_cov, cfg.eps_move_m
        )
        self.timings["undo_redo"].append(time.perf_counter() - start)
        self.timings["reapplied"].append(len(report.reapplied))
        start = time.perf_counter()
        self.global_map.add(self.vog, [k], marginals)
        self.timings["add"].append(time.perf_counter() - start)
        self.timings["closures"].append(len(accepted))
        # g. timing probes, every so many submaps (their time is kept apart)
        every = cfg.timing.every_submaps
        if every and len(self.submaps) % every == 0:
            self._probe()

    def _probe(self) -> None:
        start = time.perf_counter()
        self.probes.append(probe(self))
        self.timings["probes"].append(time.perf_counter() - start)

    def result(self) -> Result:
        """The maps and poses so far (every submap finished)."""
        self.finish_submap()
        if (
            self.config.timing.every_submaps
            and self.submaps
            and (not self.probes or self.probes[-1]["submaps"] != len(self.submaps))
        ):
            self._probe()
        has_truth = all(t is not None for t in self._scan_truth)
        return Result(
            config=self.config,
            global_map=self.global_map,
            vog=self.vog,
            standard_map=self.standard_map,
            confidence_map=self.confidence_map,
            submaps=tuple(self.submaps),
            optimized=self.vog.poses(),
            loop_closures=tuple(self.accepted),
            rejected=tuple(self.rejected),
            timings=dict(self.timings),
            metadata=self.metadata,
            scan_time_s=np.concatenate(self._scan_time) if self._scan_time else np.zeros(0),
            scan_navigation=_stack(self._scan_nav),
            scan_truth=_stack(self._scan_truth) if has_truth else None,
            truth_vog=self.truth_vog if has_truth else None,
            probes=tuple(self.probes),
        )

    def _confidence_map(self) -> ConfidenceMap:
        """A confidence-rich map beside the standard one: the same voxels and reach; range noise
        from the sensor, at least half a voxel (the sensor model's spread over a voxel)."""
        cfg = self.config.map
        noise = sensors.from_metadata(self.metadata).range_noise_m
        return ConfidenceMap(
            CrmConfig(voxel_size=cfg.voxel_size, max_range=self.reach_m, range_sigma_m=max(noise, cfg.voxel_size / 2))
        )

    def _integrate_submap(self, scans: ScanBatch) -> None:
        """The complete submap: its base at the middle scan, every scan integrated in that frame."""
        start = time.perf_counter()
        middle = len(scans) // 2
        base = scans.pose_nav[middle]
        truth = None if scans.pose_truth is None else scans.pose_truth[middle]
        origins, endpoints = scans.world(inverse(base) @ scans.pose_nav, self.reach_m)
        returns = endpoints[scans.returned]
        # the same beams placed by the truth, in the frame of the base's true pose
        true_rays = None if truth is None else scans.world(inverse(truth) @ scans.pose_truth, self.reach_m)
        rigid = None if truth is None else rigid_truth(returns, true_rays[1][scans.returned], truth)
        self.submaps.append(
            SubmapRecord(scans.first, len(scans), scans.first + middle, float(scans.time_s[middle]), base, truth, rigid)
        )
        i = self.vog.add_submap(base if self.graph is None else self._predicted_pose(base))
        self.vog.submap(i).integrate_scans(*mapped_beams(origins, endpoints, scans.invalid))
        self.timings["integration"].append(time.perf_counter() - start)
        self.clouds.append(voxel_means(returns, self.config.map.voxel_size))
        if truth is not None:  # the ceiling: the same submap from true poses, at its true pose
            start = time.perf_counter()
            j = self.truth_vog.add_submap(truth)
            self.truth_vog.submap(j).integrate_scans(*mapped_beams(*true_rays, scans.invalid))
            self.timings["truth_maps"].append(time.perf_counter() - start)

    def _predicted_pose(self, base_nav: np.ndarray) -> np.ndarray:
        """Where the optimised previous submap puts a new base pose (navigation's relative motion)."""
        previous = self.graph.num_submaps - 1
        return self.graph.poses()[previous] @ inverse(self.submaps[previous].T_world_base_nav) @ base_nav


def rigid_truth(built: np.ndarray, true: np.ndarray, T_world_base_truth: np.ndarray) -> np.ndarray:
    """T_world_base (4,4): the base's true rotation and the translation that puts the returns
    `built` (K,3, in the submap's frame, placed by navigation) closest to their true positions
    `true` (K,3, in the frame of the base's true pose) in the least-squares sense: the base
    moved by their mean offset. (Fitting the rotation too would trade a small turn of the whole
    swath against metres at its base.) The base's true pose when there are no returns."""
    T = T_world_base_truth.copy()
    if len(built):
        T[:3, 3] += T[:3, :3] @ np.mean(true - built, axis=0)
    return T


def voxel_means(points: np.ndarray, voxel_size: float) -> np.ndarray:
    """The mean of the points in each voxel (K,3), sorted by voxel: a cloud as dense as the map,
    as precise as the sensor (loop closures align these, not voxel centres)."""
    if len(points) == 0:
        return np.zeros((0, 3))
    keys = np.floor(points / voxel_size).astype(np.int64)
    _, inverse_index, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse_index.reshape(-1), points)
    return sums / counts[:, None]


def _stack(parts: list) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros((0, 4, 4))
