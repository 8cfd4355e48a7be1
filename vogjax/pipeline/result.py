"""What a pipeline run produced: the maps, the graph's poses, loop closures and timings."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from vogjax.config import PipelineConfig
from vogjax.geometry import align_xy_yaw, inverse, log_se3
from vogjax.maps import ConfidenceMap, GlobalMap, VogMap, VoxelMap
from vogjax.slam import LoopClosure, Rejection


@dataclasses.dataclass(frozen=True)
class SubmapRecord:
    """One submap as the pipeline cut it: its first scan, how many scans it holds, its base
    scan (the middle one: see `vogjax.pipeline.mapper`), the time of the base scan, and the
    base pose by navigation and (when the run has it) by ground truth, and its rigid truth: the
    true rotation with the translation that puts the submap's returns, as navigation placed
    them in it, closest to where they truly are (least squares). Drift inside a submap bends
    it; the rigid truth is where a registration of the whole bent submap belongs, and differs
    from the base's true pose by the bend.

    Attributes
    ----------
    first_scan : int
        Index of its first scan in the run.
    scans : int
        Scans it holds.
    base_scan : int
        Index of its base scan (the middle one).
    time_s : float
        Time of the base scan, seconds.
    T_world_base_nav : (4, 4) ndarray of float64
        The base pose by navigation.
    T_world_base_truth : (4, 4) ndarray of float64 or None
        The base pose by ground truth (None without it).
    T_world_base_rigid : (4, 4) ndarray of float64 or None
        Its rigid truth (None without ground truth).
    """

    first_scan: int
    scans: int
    base_scan: int
    time_s: float
    T_world_base_nav: np.ndarray
    T_world_base_truth: np.ndarray | None
    T_world_base_rigid: np.ndarray | None = None


@dataclasses.dataclass(frozen=True, kw_only=True)
class Result:
    """The maps (`global_map` kept online, `vog` the virtual map at the optimised poses,
    `standard_map` from navigation poses or None, `confidence_map` the same scans in a
    confidence-rich map or None), one `SubmapRecord` per submap, the optimised
    base poses (N,4,4), loop closures by verdict, per-step `timings` (step -> seconds per
    submap or per batch; "reapplied" and "closures" count per submap), every scan's time (S,),
    navigation and true pose (S,4,4), `truth_vog` (the submaps from true poses, or None), the
    timing `probes` (dicts: submaps, full_merge_s, query_global_s, query_virtual_s) and `returns`
    (total: returns read; beyond_reach: those past reach_m, the map's range or the sensor's,
    which became free space up to it).

    Attributes
    ----------
    config : PipelineConfig
        The settings it was mapped with.
    global_map : GlobalMap
        The online global map (Algorithm 1).
    vog : VogMap
        The submaps at the optimised poses (the virtual map).
    standard_map : VoxelMap or None
        Every scan at its navigation pose, without SLAM (None when off).
    confidence_map : ConfidenceMap or None
        The confidence-rich map of the same scans (None when off).
    submaps : tuple of SubmapRecord
        One per submap.
    optimized : (N, 4, 4) ndarray of float64
        The optimised base poses.
    loop_closures : tuple of LoopClosure
        The closures accepted.
    rejected : tuple of Rejection
        The candidates rejected, with their reasons.
    timings : dict
        Step -> seconds per submap or per batch ("reapplied" and "closures": counts per submap).
    metadata : dict
        The run's metadata.
    scan_time_s : (S,) ndarray of float64
        Every scan's time.
    scan_navigation : (S, 4, 4) ndarray of float64
        Every scan's navigation pose (corrected by scan matching, when that is on).
    scan_truth : (S, 4, 4) ndarray of float64 or None
        Every scan's true pose (None without ground truth).
    truth_vog : VogMap or None
        The submaps built from true poses (None without ground truth).
    probes : tuple of dict
        The timing probes.
    returns : dict
        ``total``, ``beyond_reach`` and ``reach_m``.
    scan_odometry : (S, 4, 4) ndarray of float64 or None
        Every scan's pose as the run recorded it, when scan matching corrected it (None when
        scan matching is off: then it is `scan_navigation`).
    scan_matching : dict
        ``enabled``, the scans ``registered`` to the local map, and those due for registration
        that ``failed`` (no local map yet, too few returns, no convergence or too large a
        move: they kept the odometry's motion).
    slam_on_second_thread : bool
        Whether each submap's SLAM step ran on a second thread beside the map work
        (`Mapper(overlap=True)`; `pipeline.run` by `PipelineConfig.slam_thread`).
    """

    config: PipelineConfig
    global_map: GlobalMap
    vog: VogMap
    standard_map: VoxelMap | None
    confidence_map: ConfidenceMap | None
    submaps: tuple[SubmapRecord, ...]
    optimized: np.ndarray
    loop_closures: tuple[LoopClosure, ...]
    rejected: tuple[Rejection, ...]
    timings: dict
    metadata: dict
    scan_time_s: np.ndarray
    scan_navigation: np.ndarray
    scan_truth: np.ndarray | None
    truth_vog: VogMap | None = None
    probes: tuple = ()
    returns: dict = dataclasses.field(default_factory=dict)
    scan_odometry: np.ndarray | None = None
    scan_matching: dict = dataclasses.field(default_factory=dict)
    slam_on_second_thread: bool = False

    @property
    def scans(self) -> int:
        """Scans mapped."""
        return len(self.scan_navigation)

    @property
    def duration_s(self) -> float:
        """Time the run covers: its scans times their mean period."""
        t = self.scan_time_s
        return float((t[-1] - t[0]) * len(t) / (len(t) - 1)) if len(t) > 1 else 0.0

    @property
    def navigation(self) -> np.ndarray:
        """(N,4,4) submap base poses by navigation."""
        return np.array([s.T_world_base_nav for s in self.submaps]).reshape(-1, 4, 4)

    @property
    def truth(self) -> np.ndarray | None:
        """(N,4,4) true submap base poses; None when the run has no ground truth."""
        if self.scan_truth is None:
            return None
        return np.array([s.T_world_base_truth for s in self.submaps]).reshape(-1, 4, 4)

    @property
    def rigid_truth(self) -> np.ndarray | None:
        """(N,4,4) rigid truths of the submaps (see SubmapRecord); None without ground truth."""
        if self.scan_truth is None or any(s.T_world_base_rigid is None for s in self.submaps):
            return None
        return np.array([s.T_world_base_rigid for s in self.submaps]).reshape(-1, 4, 4)

    @property
    def submap_first_scan(self) -> np.ndarray:
        """(N,) int64: each submap's first scan."""
        return np.array([s.first_scan for s in self.submaps], dtype=np.int64)

    @property
    def submap_base_scan(self) -> np.ndarray:
        """(N,) int64: each submap's base scan."""
        return np.array([s.base_scan for s in self.submaps], dtype=np.int64)

    @property
    def metrics(self) -> dict:
        """What needs no ground-truth map: base-pose RMS error of navigation and optimised poses
        (m; when the run has true poses; with scan matching on, also of the odometry as
        recorded), as they are and after the best x-y-yaw rigid fit to
        the truth (`*_aligned`), and loop closures by verdict."""
        errors = {}
        truth = self.truth
        if truth is not None:
            pairs = {"navigation": (self.navigation, truth), "optimized": (self.optimized, truth)}
            if self.scan_odometry is not None:  # the odometry as recorded, before scan matching
                pairs["odometry"] = (self.scan_odometry[self.submap_base_scan], truth)
            rigid = self.rigid_truth
            if rigid is not None:  # how far the bends move the rigid truths, and SLAM from them
                pairs.update(rigid_truth=(rigid, truth), optimized_vs_rigid_truth=(self.optimized, rigid))
            for name, (poses, reference) in pairs.items():
                offsets = poses[:, :3, 3] - reference[:, :3, 3]
                errors[name] = float(np.sqrt(np.mean(np.sum(offsets**2, axis=1))))
            # ... and after the best x-y-yaw fit to the truth: the graph's anchor (the first base
            # pose, already drifted) sets where the whole solution sits; the rest is its shape
            for name in ("navigation", "optimized"):
                positions, reference = pairs[name][0][:, :3, 3], truth[:, :3, 3]
                T = self.gauge_alignment(name)
                offsets = positions @ T[:3, :3].T + T[:3, 3] - reference
                errors[name + "_aligned"] = float(np.sqrt(np.mean(np.sum(offsets**2, axis=1))))
        rejected = {}
        for r in self.rejected:
            rejected[r.reason] = rejected.get(r.reason, 0) + 1
        closures = {"accepted": len(self.loop_closures), "rejected": len(self.rejected), "rejected_by_reason": rejected}
        if truth is not None:
            closures.update(self.closure_errors())
        closures["rejections"] = self.rejection_errors()
        return {"trajectory_rmse_m": errors, "loop_closures": closures}

    def rejection_errors(self) -> list[dict]:
        """Per rejected candidate: i, k, the reason, the figure that failed and its bound, and
        (when the alignment ran and the run has truth) the translation error of what it found
        against the true and the rigid-truth relative pose (m, all three directions): whether
        the test that refused it was right.

        Returns
        -------
        list of dict
            One per `Rejection`, in the order they were made; NaN where a figure is undefined.
        """
        truth, rigid = self.truth, self.rigid_truth
        out = []
        for r in self.rejected:
            entry = {"i": r.i, "k": r.k, "reason": r.reason, "value": r.value, "limit": r.limit}
            for suffix, poses in (("", truth), ("_rigid", rigid)):
                if poses is None:
                    continue
                if r.T_i_k is None:
                    entry["translation_m" + suffix] = float("nan")
                    continue
                twist = log_se3(inverse(inverse(poses[r.i]) @ poses[r.k]) @ r.T_i_k)
                entry["translation_m" + suffix] = float(np.linalg.norm(twist[3:]))
            out.append(entry)
        return out

    def gauge_alignment(self, which: str = "optimized") -> np.ndarray | None:
        """T_world_true_world_est (4,4): the x-y-yaw motion that best fits the "optimized" or
        "navigation" base positions to the true ones (least squares; z untouched), or None
        without ground truth. Loop closures and odometry are relative, so where the whole
        solution sits in x, y and yaw is set by the graph's anchor (the first base pose as
        navigation gives it, already drifted): this fit takes that out and leaves the shape.

        Parameters
        ----------
        which : str, optional
            "optimized" or "navigation".

        Returns
        -------
        (4, 4) ndarray of float64 or None
            The fit, or None without ground truth.
        """
        truth = self.truth
        if truth is None:
            return None
        poses = {"optimized": self.optimized, "navigation": self.navigation}[which]
        return align_xy_yaw(poses[:, :3, 3], truth[:, :3, 3])

    def closure_errors(self, max_translation_m: float = 0.2, max_rotation_deg: float = 1.0) -> dict:
        """Each accepted closure against the true relative pose, in the directions it constrains
        (all six for a full factor): translation and rotation error, and `precision`, the share
        within `max_translation_m` and `max_rotation_deg` (NaN without closures). The same
        against the submaps' rigid truths (`*_rigid`, `precision_rigid`): what is left is mostly
        the registration's own error, the bends drift put inside the two submaps taken out.
        And `precision_ceiling`, what a registration that recovered each pair's rigid truths
        exactly would score: the share of the accepted pairs whose rigid truths relate within
        the same bounds of the true relative pose (`*_bend` per closure).

        Parameters
        ----------
        max_translation_m : float, optional
            Translation error a correct closure stays within, metres.
        max_rotation_deg : float, optional
            Rotation error a correct closure stays within, degrees.

        Returns
        -------
        dict
            ``precision``, ``precision_rigid``, ``precision_ceiling`` and ``errors`` (one entry
            per closure).
        """
        errors = []
        truth, rigid = self.truth, self.rigid_truth

        def relative(poses, c):
            return inverse(poses[c.i]) @ poses[c.k]

        for c in self.loop_closures:
            basis = np.eye(6) if c.basis is None else c.basis
            error = {
                "i": c.i,
                "k": c.k,
                "directions": int(basis.shape[1]),
                "fitness_m2": c.fitness,
                "overlap": c.overlap,
                "ambiguity": c.ambiguity,
                "distance": c.distance,
            }
            measured = {"": (truth, c.T_i_k), "_rigid": (rigid, c.T_i_k)}
            if rigid is not None:
                measured["_bend"] = (truth, relative(rigid, c))
            for suffix, (poses, T_i_k) in measured.items():
                if poses is None:
                    continue
                rotation, translation = dataclasses.replace(c, T_i_k=T_i_k).errors_at_centre(relative(poses, c))
                error["translation_m" + suffix] = translation
                error["rotation_deg" + suffix] = float(np.degrees(rotation))
            errors.append(error)
        out = {}
        for suffix, name, known in (
            ("", "precision", truth is not None),
            ("_rigid", "precision_rigid", rigid is not None),
            ("_bend", "precision_ceiling", truth is not None and rigid is not None),
        ):
            if not known:
                continue
            good = [
                e["translation_m" + suffix] <= max_translation_m and e["rotation_deg" + suffix] <= max_rotation_deg
                for e in errors
            ]
            out[name] = float(np.mean(good)) if errors else float("nan")
        return {**out, "errors": errors}

    @functools.cached_property
    def full_merge(self) -> GlobalMap:
        """Every submap merged from scratch at its optimised pose (what `global_map` must equal
        when Algorithm 1's thresholds are zero)."""
        merged = GlobalMap(self.config.map, self.global_map.device)
        merged.merge(self.vog)
        return merged

    @functools.cached_property
    def truth_merge(self) -> GlobalMap | None:
        """The submaps built from true poses, merged at their true poses (None without truth)."""
        if self.truth_vog is None:
            return None
        merged = GlobalMap(self.config.map, self.global_map.device)
        merged.merge(self.truth_vog)
        return merged

    @functools.cached_property
    def rigid_truth_merge(self) -> GlobalMap | None:
        """The pipeline's submaps merged at their rigid truths: one good placement of these
        rigid, navigation-bent submaps (None without ground truth)."""
        rigid = self.rigid_truth
        if rigid is None:
            return None
        merged = GlobalMap(self.config.map, self.global_map.device)
        merged.merge(self.vog.view(poses=rigid))
        return merged

    @functools.cached_property
    def navigation_merge(self) -> GlobalMap:
        """The submaps merged at their navigation poses: the map without loop closures."""
        merged = GlobalMap(self.config.map, self.global_map.device)
        merged.merge(self.vog.view(poses=self.navigation))
        return merged

    def scan_poses(self, which: str) -> np.ndarray | None:
        """Per-scan poses.

        Parameters
        ----------
        which : str
            "navigation", "odometry" (as the run recorded it, before scan matching), "truth"
            or "optimized" (each scan moved rigidly with its submap's base pose, as the maps
            place it).

        Returns
        -------
        (S, 4, 4) ndarray of float64 or None
            The poses; None for "truth" without ground truth and for "odometry" without scan
            matching.

        Raises
        ------
        ValueError
            If `which` is none of those.
        """
        if which == "navigation":
            return self.scan_navigation
        if which == "odometry":
            return self.scan_odometry
        if which == "truth":
            return self.scan_truth
        if which != "optimized":
            raise ValueError(f"which must be 'navigation', 'odometry', 'truth' or 'optimized', got {which!r}")
        submap = np.searchsorted(self.submap_first_scan, np.arange(self.scans), side="right") - 1
        correction = self.optimized @ np.linalg.inv(self.navigation)
        return correction[submap] @ self.scan_navigation
