"""The mapper: scans in, submaps, SLAM and the loop-closure-consistent global map out.

Feed it scans batch by batch (`add`), from a recorded run or live from a vehicle, and ask for
the `result()` at any time. Per batch it:
0. with scan matching on (`ScanMatchingConfig`), corrects the batch's odometry by registering
   its scans to a local map: the corrected poses are the navigation from here on,
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
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from vogjax import sensors
from vogjax.config import CrmConfig, PipelineConfig
from vogjax.geometry import inverse
from vogjax.io.dataset import MAX_BEAMS, ScanBatch, check_scans
from vogjax.maps import ConfidenceMap, GlobalMap, VogMap, VoxelMap
from vogjax.maps.submaps import Submap
from vogjax.pipeline.cutter import SubmapCutter
from vogjax.pipeline.probes import probe
from vogjax.pipeline.result import Result, SubmapRecord
from vogjax.sensors import mapped_beams
from vogjax.slam import LoopClosureDetector, PoseGraph, Rejection, ScanMatcher
from vogjax.slam.backend import odometry_step
from vogjax.slam.clouds import voxel_means


class Mapper:
    """Scans in, submaps, SLAM and the global map out (see the module's docstring).

    Parameters
    ----------
    config : PipelineConfig, optional
        The pipeline's settings.
    metadata : dict, optional
        The run's metadata (sensor, scene).
    overlap : bool, optional
        Run each submap's SLAM step (pose-graph node, loop closures, iSAM2) on a second thread
        while the next scans are integrated; the global map takes each result in before the
        next submap joins the graph, so the maps, poses and closures are the same bits as
        without. Between `add` calls the last submap's SLAM may still be in flight: `sync()`
        (or `finish_submap()`, `result()`) brings everything up to date. The detector then
        runs on the host even when the maps are on a GPU (the host's and the device's front
        ends agree but at near-exact ties), so no two threads launch on one device. Default
        False (a live mapper, queried between batches, sees every finished submap);
        `pipeline.run` passes `PipelineConfig.slam_thread`.

    Raises
    ------
    ValueError
        When config is not a PipelineConfig.
    """

    def __init__(self, config: PipelineConfig | None = None, metadata: dict | None = None, overlap: bool = False):
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
        # on a GPU the front end's searches run beside the maps (unless SLAM has its own thread:
        # then on the host, beside the maps' kernels); on the CPU the FFTs and trees win
        on_gpu = self.global_map.device.is_cuda and not overlap
        front_end = self.global_map.device if on_gpu else None
        self.detector = LoopClosureDetector(config.nav_noise, config.loop_closure, front_end)
        self.cutter = SubmapCutter(config)
        self.scan_matcher = ScanMatcher(config.scan_matching) if config.scan_matching.enabled else None
        self.overlap = overlap
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="vogjax-slam") if overlap else None
        self._slam_future: Future | None = None
        self._bounds: list = []  # per finished submap: its observed box (SubmapRecord order)
        self.timings = defaultdict(list)
        self.submaps: list[SubmapRecord] = []
        self.accepted, self.rejected = [], []
        self.probes: list[dict] = []
        self.clouds: list[np.ndarray] = []  # per submap: its returns, one mean point per voxel
        self.scans = 0
        self.returns = {"total": 0, "beyond_reach": 0}  # returns read, and those past reach_m
        self._pending: list[ScanBatch] = []  # the scans of the submap being filled
        self._scan_time, self._scan_nav, self._scan_truth = [], [], []
        self._scan_odometry = []  # the poses as recorded, when scan matching corrects them
        self._beams = 0  # per scan, set by the first batch

    @property
    def num_submaps(self) -> int:
        """Finished submaps: those in the pose graph and the global map."""
        return len(self.submaps)

    def add(self, batch: ScanBatch) -> None:
        """Integrate a batch of consecutive scans; finish every submap it completes.

        The batch is checked as a run file's scans are (finite, rigid poses; times increasing
        from the last scan added; the beam count and ground truth of the first batch) before
        anything changes.

        Parameters
        ----------
        batch : ScanBatch
            Consecutive scans of the run.

        Raises
        ------
        ValueError
            If the batch is not finite, its poses not rigid, its times not increasing, its
            beams or ground truth differ from the first batch's, or a submap it would close is
            based at a pose the pose graph cannot take (a jump or a time step it cannot weigh,
            `slam.backend.odometry_step`). Nothing changes then, but with scan matching on the
            matcher has taken the batch's scans.
        """
        self._check(batch)
        if not len(batch):
            return
        if self.scan_matcher is not None:  # the odometry corrected first: everything below uses it
            start = time.perf_counter()
            corrected = self.scan_matcher.correct(
                batch.time_s, batch.pose_nav, lambda j: vehicle_returns(batch, j, self.reach_m)
            )
            self._scan_odometry.append(batch.pose_nav)
            batch = dataclasses.replace(batch, pose_nav=corrected)
            self.timings["scan_matching"].append(time.perf_counter() - start)
        cuts = self._cuts(batch)
        self._check_odometry(self._closed_by(batch, cuts))  # before the maps or the graph take any of it
        self._scan_time.append(batch.time_s)
        self._scan_nav.append(batch.pose_nav)
        self._scan_truth.append(batch.pose_truth)
        returned = batch.ranges[batch.returned]
        self.returns["total"] += returned.size
        self.returns["beyond_reach"] += int(np.count_nonzero(returned > self.reach_m))
        # 1. the maps without SLAM: every scan at its navigation pose, in one batch (an invalid
        # beam, its surface within the blind distance, clears nothing: it is left out)
        beams = batch.beams(batch.pose_nav, self.reach_m)
        for name, whole_map in (("standard_map", self.standard_map), ("confidence_map", self.confidence_map)):
            if whole_map is not None:
                start = time.perf_counter()
                whole_map.integrate_scans(*beams)
                self.timings[name].append(time.perf_counter() - start)
        # 2. cut into submaps, holding each one's scans until it is complete
        for first, last, full in cuts:
            if last > first:
                self._pending.append(batch.rows(first, last))
            if full:
                self._close_submap()
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

    def _cuts(self, batch: ScanBatch) -> list[tuple[int, int, bool]]:
        """How `add` cuts `batch` into the submaps, changing nothing: (first, last, full) per
        step, rows first:last joining the submap being filled, which is then closed if full."""
        cuts = []
        held = sum(len(part) for part in self._pending)
        started_s = self._pending[0].time_s[0] if self._pending else None
        first = 0
        while first < len(batch):
            started_s = batch.time_s[first] if started_s is None else started_s
            room = max(self.cutter.room(held, batch.time_s[first:] - started_s), 0 if held else 1)
            last = first + room
            full = last < len(batch)
            cuts.append((first, last, full))
            held, first = (0, last) if full else (held + room, last)
            started_s = None if full else started_s
        return cuts

    def _closed_by(self, batch: ScanBatch, cuts: list[tuple[int, int, bool]]) -> list[tuple[np.ndarray, float]]:
        """(base pose, base time) of each submap that `cuts` of `batch` close."""
        closed = []
        parts = [(part.time_s, part.pose_nav) for part in self._pending]
        for first, last, full in cuts:
            parts.append((batch.time_s[first:last], batch.pose_nav[first:last]))
            if full:
                closed.append(_base_of(parts))
                parts = []
        return closed

    def _check_odometry(self, bases: list[tuple[np.ndarray, float]]) -> None:
        """Refuse base poses the pose graph would refuse (`slam.backend.odometry_step`), before
        any map or the graph has changed: a jump or a time step it cannot weigh, found midway
        through a run, would leave the maps ahead of the graph."""
        previous = (self.submaps[-1].T_world_base_nav, self.submaps[-1].time_s) if self.submaps else None
        for T, time_s in bases:
            if previous is not None:
                try:
                    odometry_step(self.config.nav_noise, previous[0], T, time_s - previous[1])
                except ValueError as error:
                    raise ValueError(f"batch: the submap based at t = {time_s:.9g} s: {error}") from None
            previous = (T, time_s)

    def finish_submap(self) -> None:
        """Close the submap being filled (if any) and bring SLAM and the global map up to date:
        every finished submap is then in the pose graph and the global map.

        Raises
        ------
        ValueError
            If the pose graph cannot take the submap's base pose (a jump, or a time step, it
            cannot weigh); nothing changes then.
        """
        if self._pending:
            self._check_odometry([_base_of([(part.time_s, part.pose_nav) for part in self._pending])])
        self._close_submap()
        self.sync()

    def sync(self) -> None:
        """Wait for the SLAM step running on the second thread (if any) and take its result into
        the maps; after it every finished submap is in the pose graph and the global map."""
        if self._slam_future is None:
            return
        future, self._slam_future = self._slam_future, None
        self._take_slam(*future.result())

    def _close_submap(self) -> None:
        """Integrate the submap being filled, then hand it to SLAM: at once, or (with `overlap`)
        on the second thread while the next scans are integrated. The maps and the graph see
        the same steps in the same order either way, so the results are the same bits."""
        if not self._pending:
            return
        scans = ScanBatch.concatenate(self._pending)
        self._pending = []
        staged = self._integrate_submap(scans)  # map work: needs nothing from SLAM
        self.sync()  # the previous submap's SLAM and map update, before this one joins them
        record, submap, cloud, bounds = staged
        k = len(self.submaps)
        self.vog.add_submap(record.T_world_base_nav if self.graph is None else self._predicted_pose(record), submap)
        self.submaps.append(record)
        self.clouds.append(cloud)
        self._bounds.append(bounds)
        inputs = (
            k,
            list(self.clouds),
            list(self._bounds),
            np.array([s.T_world_base_nav for s in self.submaps]),
            np.array([s.time_s for s in self.submaps]),
        )
        if self._executor is None:
            self._take_slam(*self._slam(*inputs))
        else:
            self._slam_future = self._executor.submit(self._slam, *inputs)

    def _slam(self, k: int, clouds: list, bounds: list, nav_bases: np.ndarray, times_s: np.ndarray) -> tuple:
        """The SLAM step of submap k, on the pose graph and the detector only (no map): its node,
        loop closures and the graph's update. Returns (k, poses, accepted, rejected)."""
        cfg = self.config
        # a. pose-graph node with its xyh and zpr factors
        start = time.perf_counter()
        if self.graph is None:
            self.graph = PoseGraph(cfg.nav_noise, prior_pose=nav_bases[0], config=cfg.pose_graph)
            self.graph.add_submap(nav_bases[0])
        else:
            self.graph.add_submap(nav_bases[k], times_s[k] - times_s[k - 1])
        poses = self.graph.update()
        self.timings["isam2"].append(time.perf_counter() - start)
        # b. loop closures against earlier submaps
        start = time.perf_counter()
        found, rejected = self.detector.detect(
            k, clouds, bounds, poses, nav_bases, times_s, self.graph.relative_covariance
        )
        self.timings["loop_closure"].append(time.perf_counter() - start)
        for phase, seconds in self.detector.seconds.items():  # its parts
            self.timings[phase].append(seconds)
        # c. iSAM2 with the new constraints, each screened by the graph first
        start = time.perf_counter()
        accepted = []
        for closure in found:
            check = self.graph.add_loop_closure(closure.i, closure.k, closure.T_i_k, closure.covariance, closure.basis)
            if check.accepted:
                accepted.append(dataclasses.replace(closure, distance=check.distance))
            else:
                rejected.append(
                    Rejection(
                        closure.i,
                        closure.k,
                        "inconsistent",
                        closure.fitness,
                        _deviation_m(nav_bases[closure.i], nav_bases[k], closure.T_i_k),
                        check.distance,
                        check.limit,
                        closure.T_i_k,
                    )
                )
        poses = self.graph.update()
        self.timings["isam2"][-1] += time.perf_counter() - start
        return k, poses, accepted, rejected

    def _take_slam(self, k: int, poses: np.ndarray, accepted: list, rejected: list) -> None:
        """Submap k's SLAM result into the maps: the virtual map's poses, Algorithm 1's undo and
        redo in the global map, the new submap added (the graph is idle here)."""
        cfg = self.config
        self.accepted += accepted
        self.rejected += rejected
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
        if every and (k + 1) % every == 0:
            self._probe()

    def close(self) -> None:
        """Finish the SLAM step in flight (if any) and stop the second thread."""
        try:
            self.sync()
        finally:
            if self._executor is not None:
                self._executor.shutdown(wait=True)
                self._executor = None

    def abandon(self) -> None:
        """Stop the second thread without waiting for the SLAM step in flight or taking it into
        the maps (after an error or an interrupt: the maps stay as they were, the step's own
        result or error is dropped)."""
        self._slam_future = None
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    def _probe(self) -> None:
        start = time.perf_counter()
        self.probes.append(probe(self))
        self.timings["probes"].append(time.perf_counter() - start)

    def result(self) -> Result:
        """The maps and poses so far (every submap finished).

        Returns
        -------
        Result
            The maps, poses, closures and timings.
        """
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
            scan_odometry=_stack(self._scan_odometry) if self.scan_matcher is not None else None,
            scan_truth=_stack(self._scan_truth) if has_truth else None,
            truth_vog=self.truth_vog if has_truth else None,
            probes=tuple(self.probes),
            returns={**self.returns, "reach_m": self.reach_m},
            scan_matching={
                "enabled": self.scan_matcher is not None,
                "registered": self.scan_matcher.registered if self.scan_matcher else 0,
                "failed": self.scan_matcher.failed if self.scan_matcher else 0,
            },
            slam_on_second_thread=self.overlap,
        )

    def _confidence_map(self) -> ConfidenceMap:
        """A confidence-rich map beside the standard one: the same voxels and reach; range noise
        from the sensor, at least half a voxel (the sensor model's spread over a voxel)."""
        cfg = self.config.map
        noise = sensors.from_metadata(self.metadata).range_noise_m
        return ConfidenceMap(
            CrmConfig(voxel_size=cfg.voxel_size, max_range=self.reach_m, range_sigma_m=max(noise, cfg.voxel_size / 2))
        )

    def _integrate_submap(self, scans: ScanBatch) -> tuple:
        """The complete submap: its base at the middle scan, every scan integrated in that frame,
        outside the virtual map (SLAM may still be running on the previous one); returns its
        (SubmapRecord, Submap, cloud of returns, bounds). What only a run with true poses does
        (the rigid truth, the true-pose submap) is timed apart, as "truth_maps"."""
        start = time.perf_counter()
        middle = len(scans) // 2
        base = scans.pose_nav[middle]
        origins, endpoints = scans.world(inverse(base) @ scans.pose_nav, self.reach_m)
        returns = endpoints[scans.returned]
        submap = Submap(self.config.map, self.vog.device)
        submap.integrate_scans(*mapped_beams(origins, endpoints, scans.invalid))
        cloud_voxel = self.config.loop_closure.registration_voxel_m or self.config.map.voxel_size
        cloud, bounds = voxel_means(returns, cloud_voxel), submap.bounds()
        self.timings["integration"].append(time.perf_counter() - start)
        truth = rigid = None
        if scans.pose_truth is not None:  # the ceiling: the same submap from true poses, at its true pose
            start = time.perf_counter()
            truth = scans.pose_truth[middle]
            # the same beams placed by the truth, in the frame of the base's true pose
            true_rays = scans.world(inverse(truth) @ scans.pose_truth, self.reach_m)
            rigid = rigid_truth(returns, true_rays[1][scans.returned], truth)
            j = self.truth_vog.add_submap(truth)
            self.truth_vog.submap(j).integrate_scans(*mapped_beams(*true_rays, scans.invalid))
            self.timings["truth_maps"].append(time.perf_counter() - start)
        record = SubmapRecord(
            scans.first, len(scans), scans.first + middle, float(scans.time_s[middle]), base, truth, rigid
        )
        return record, submap, cloud, bounds

    def _predicted_pose(self, record: SubmapRecord) -> np.ndarray:
        """Where the optimised previous submap puts a new base pose (navigation's relative motion)."""
        previous = self.graph.num_submaps - 1
        return self.graph.poses()[previous] @ inverse(self.submaps[previous].T_world_base_nav) @ record.T_world_base_nav


def _base_of(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, float]:
    """(pose, time) of the middle scan of a submap's (times, poses) parts: its base, as
    `_integrate_submap` takes it."""
    times = np.concatenate([times for times, _ in parts])
    poses = np.concatenate([poses for _, poses in parts])
    middle = len(times) // 2
    return poses[middle], float(times[middle])


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


def vehicle_returns(batch: ScanBatch, j: int, reach_m: float) -> np.ndarray:
    """Scan j's returns within `reach_m` (as the maps take them), in the vehicle frame (N, 3)."""
    scan = batch.rows(j, j + 1)
    _, endpoints = scan.world(np.eye(4)[None], reach_m)
    return endpoints[0][scan.returned[0] & (scan.ranges[0] <= reach_m)]


def _deviation_m(T_world_i_nav: np.ndarray, T_world_k_nav: np.ndarray, T_i_k: np.ndarray) -> float:
    """x-y offset (m) of a closure from the navigation's relative pose, as the detector measures it."""
    return float(np.linalg.norm((inverse(inverse(T_world_i_nav) @ T_world_k_nav) @ T_i_k)[:2, 3]))


def _stack(parts: list) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros((0, 4, 4))
