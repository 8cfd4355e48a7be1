"""Scan matching over the recorded odometry: a lidar registered against its own recent scans.

Wheel odometry lets the heading random-walk (0.18 degrees per square-root second); a spinning
lidar sees the same walls from one scan to the next, so registering its scans against a local
map of the last few seconds keeps the heading and position within centimetres, before any
loop closure. The corrected poses replace the odometry for everything downstream (the maps
without SLAM, the submaps' scans, the pose graph's odometry factors), which matters most for the
first submap: it anchors the graph, and closures between submaps cannot observe its heading.

The matcher is causal and per scan, like the mapper it feeds: the same scans give the same
poses however they are split into batches.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from vogjax.config import ScanMatchingConfig
from vogjax.geometry import inverse, rigid_poses
from vogjax.slam.clouds import voxel_means
from vogjax.slam.icp import MIN_POINTS, icp, prepare_target
from vogjax.validation import float_array

# a scan time within this share of a registration slot of the slot's start counts as in it:
# times that are running sums of 0.1 s reach 0.4999...9 s
SLOT_TOLERANCE = 1e-6


class ScanMatcher:
    """Corrects a run's odometry by registering its scans to a local map (`ScanMatchingConfig`).

    Time is cut into slots of `every_s` from the first scan; the first scan of each slot is
    due for registration: its returns (their means per `voxel_m` voxel, in the vehicle frame)
    are aligned by ICP to the local map, starting where the odometry's motion since the last
    registration puts them. The correction this gives (``T_world_matched @
    inverse(T_world_odometry)``) moves every scan until the next registration. The first scan
    with returns keeps its odometry pose and starts the local map: it anchors the run.

    A due scan that is not registered keeps the odometry's motion and is counted in `failed`:
    no local map yet, too few returns, ICP did not converge, or it moved the scan farther than
    ICP's pair distance (`icp.max_correspondence_m`) from where the odometry put it (a wrong
    convergence: over `every_s` odometry is good to centimetres).

    Parameters
    ----------
    config : ScanMatchingConfig
        The matcher's settings.

    Attributes
    ----------
    registered : int
        Scans registered to the local map.
    failed : int
        Scans due for registration that were not.

    Raises
    ------
    ValueError
        If config is not a ScanMatchingConfig.
    """

    def __init__(self, config: ScanMatchingConfig):
        if not isinstance(config, ScanMatchingConfig):
            raise ValueError(f"config must be a ScanMatchingConfig, got {type(config).__name__}")
        self.config = config
        self.correction = np.eye(4)  # T_world_matched @ inverse(T_world_odometry) of the last registration
        self.registered = 0
        self.failed = 0
        self._first_s: float | None = None  # the first scan's time: slot 0 starts there
        self._last_s = -np.inf  # the last scan's time
        self._last_slot = -1
        self._local: deque = deque()  # (time_s, (K,3) world points) of the scans in the local map
        self._target = None
        self._since_rebuild = 0  # scans added to the local map since its tree was rebuilt

    def correct(
        self,
        time_s: npt.ArrayLike,
        T_world_vehicle: npt.ArrayLike,
        returns_of: Callable[[int], np.ndarray],
    ) -> np.ndarray:
        """The next scans' poses corrected by scan matching, in order; the matcher moves on past them.

        Parameters
        ----------
        time_s : (S,) array_like of float
            The scans' times, seconds, increasing (from the last call's too).
        T_world_vehicle : (S, 4, 4) array_like of float
            Their odometry poses, rigid.
        returns_of : callable
            ``returns_of(j)``: scan j's returns (N, 3), metres, in the vehicle frame; called
            only for the scans due for registration.

        Returns
        -------
        (S, 4, 4) ndarray of float64
            ``T_world_vehicle`` of each scan, corrected.

        Raises
        ------
        ValueError
            Naming the argument: times or poses of the wrong shape or not finite, poses not
            rigid, times not
            increasing, returns_of not callable or giving anything but an (N, 3) finite array;
            the matcher is then as it was before the call.
        """
        time_s = float_array("time_s", time_s, (-1,), np.float64)
        poses = rigid_poses("T_world_vehicle", T_world_vehicle, len(time_s))
        if not callable(returns_of):
            raise ValueError("returns_of must be callable: scan index -> (N, 3) returns")
        if len(time_s) and (np.any(np.diff(time_s) <= 0) or time_s[0] <= self._last_s):
            raise ValueError("time_s must increase, from the scans corrected before too")
        before = {**vars(self), "_local": deque(self._local)}  # a bad cloud midway undoes the call
        try:
            return self._correct(time_s, poses, returns_of)
        except Exception:
            vars(self).update(before)
            raise

    def _correct(self, time_s: np.ndarray, poses: np.ndarray, returns_of: Callable[[int], np.ndarray]) -> np.ndarray:
        corrected = np.empty_like(poses)
        for j, (t, odometry) in enumerate(zip(time_s, poses)):
            if self._first_s is None:
                self._first_s = float(t)
            self._last_s = float(t)
            slot = int(np.floor((t - self._first_s) / self.config.every_s + SLOT_TOLERANCE))
            guess = self.correction @ odometry
            if slot <= self._last_slot:
                corrected[j] = guess
                continue
            self._last_slot = slot
            source = voxel_means(float_array("returns_of", returns_of(j), (-1, 3), np.float64), self.config.voxel_m)
            if self._target is None:  # the local map's start: the scan keeps its pose
                if len(source) < max(MIN_POINTS, self.config.icp.normal_neighbours):
                    self.failed += 1  # nothing to anchor the local map with yet
                corrected[j] = guess
                self._remember(float(t), source, guess)
                continue
            pose = self._register(source, guess)
            if pose is None:
                self.failed += 1
                corrected[j] = guess
                continue
            self.registered += 1
            corrected[j] = pose
            self.correction = pose @ inverse(odometry)
            self._remember(float(t), source, pose)
        return corrected

    def _register(self, source: np.ndarray, guess: np.ndarray) -> np.ndarray | None:
        """The pose ICP registers `source` at to the local map from `guess`; None when it has
        too few points, does not converge or moves farther than ICP's pair distance."""
        icp_config = self.config.icp
        if len(source) < max(MIN_POINTS, icp_config.min_inliers):
            return None
        result = icp(source, self._target, guess, config=icp_config)
        T = result.T_target_source
        moved = np.linalg.norm(T[:3, 3] - guess[:3, 3]) if np.all(np.isfinite(T)) else np.inf
        return T if result.converged and moved <= icp_config.max_correspondence_m else None

    def _remember(self, t: float, source: np.ndarray, pose: np.ndarray) -> None:
        """The scan into the local map; the map's tree and normals rebuilt when due."""
        cfg = self.config
        if len(source):
            self._local.append((t, source @ pose[:3, :3].T + pose[:3, 3]))
            self._since_rebuild += 1
        while self._local and self._local[0][0] < t - cfg.window_s:
            self._local.popleft()
        every = max(1, round(cfg.refresh_s / cfg.every_s))  # registrations between rebuilds
        if not self._local or (self._target is not None and self._since_rebuild < every):
            return
        points = voxel_means(np.concatenate([cloud for _, cloud in self._local]), cfg.voxel_m)
        if len(points) >= max(MIN_POINTS, cfg.icp.normal_neighbours):
            self._target = prepare_target(points, cfg.icp)
            self._since_rebuild = 0
