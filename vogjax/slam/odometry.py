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

import numpy as np

from vogjax.config import ScanMatchingConfig
from vogjax.geometry import inverse
from vogjax.io.dataset import ScanBatch
from vogjax.slam.clouds import voxel_means
from vogjax.slam.icp import MIN_POINTS, icp, prepare_target


class ScanMatcher:
    """Corrects a run's odometry by registering its scans to a local map (`ScanMatchingConfig`).

    Every `every_s` seconds a scan's returns (their means per `voxel_m` voxel, in the vehicle
    frame) are aligned by ICP to the local map, starting where the odometry's motion since the
    last registered scan puts them; the correction this gives (``T_world_matched @
    inverse(T_world_odometry)``) moves every scan until the next registration. The first scan
    keeps its odometry pose: it anchors the run. A registration that does not converge keeps
    the odometry's motion (counted in `failed`).

    Parameters
    ----------
    config : ScanMatchingConfig
        The matcher's settings.
    reach_m : float
        Returns farther than this are left out (as the maps leave them).

    Raises
    ------
    ValueError
        If config is not a ScanMatchingConfig or reach_m is not positive.
    """

    def __init__(self, config: ScanMatchingConfig, reach_m: float):
        if not isinstance(config, ScanMatchingConfig):
            raise ValueError(f"config must be a ScanMatchingConfig, got {type(config).__name__}")
        if not reach_m > 0:
            raise ValueError(f"reach_m must be positive, got {reach_m}")
        self.config = config
        self.reach_m = float(reach_m)
        self.correction = np.eye(4)  # T_world_matched @ inverse(T_world_odometry) of the last registration
        self.registered = 0
        self.failed = 0
        self._last_s = -np.inf  # time of the last registered scan
        self._local: deque = deque()  # (time_s, (K,3) world points) of the registered scans
        self._target = None
        self._target_s = -np.inf  # time of the newest scan in the target

    def correct(self, batch: ScanBatch) -> np.ndarray:
        """The batch's poses corrected by scan matching, in order; the matcher moves on past it.

        Parameters
        ----------
        batch : ScanBatch
            The next scans of the run (checked, times increasing from the last batch's).

        Returns
        -------
        (S, 4, 4) ndarray of float64
            ``T_world_vehicle`` of each scan.
        """
        cfg = self.config
        poses = np.empty_like(batch.pose_nav, dtype=np.float64)
        for j in range(len(batch)):
            odometry = batch.pose_nav[j].astype(np.float64)
            t = float(batch.time_s[j])
            if t - self._last_s < cfg.every_s * (1 - 1e-9):  # scan times 0.1 s apart sum to 0.4999...9 s
                poses[j] = self.correction @ odometry
                continue
            source = self._returns(batch, j)
            pose = self._register(source, self.correction @ odometry)
            self.correction = pose @ inverse(odometry)
            self._last_s = t
            poses[j] = pose
            self._remember(t, source, pose)
        return poses

    def _returns(self, batch: ScanBatch, j: int) -> np.ndarray:
        """Scan j's returns within reach, their means per voxel, in the vehicle frame."""
        scan = batch.rows(j, j + 1)
        _, endpoints = scan.world(np.eye(4)[None], self.reach_m)
        points = endpoints[0][scan.returned[0]]
        return voxel_means(points, self.config.voxel_m)

    def _register(self, source: np.ndarray, guess: np.ndarray) -> np.ndarray:
        if self._target is None:  # the first scan: the anchor
            return guess
        self.registered += 1
        if len(source) < max(MIN_POINTS, self.config.icp.min_inliers):
            self.failed += 1
            return guess
        result = icp(source, self._target, guess, config=self.config.icp)
        if not (result.converged and np.all(np.isfinite(result.T_target_source))):
            self.failed += 1
            return guess
        return result.T_target_source

    def _remember(self, t: float, source: np.ndarray, pose: np.ndarray) -> None:
        """The registered scan into the local map; the map's tree rebuilt when due."""
        cfg = self.config
        self._local.append((t, source @ pose[:3, :3].T + pose[:3, 3]))
        while self._local[0][0] < t - cfg.window_s:
            self._local.popleft()
        if self._target is not None and t - self._target_s < cfg.refresh_s:
            return
        points = voxel_means(np.concatenate([cloud for _, cloud in self._local]), cfg.voxel_m)
        if len(points) >= max(MIN_POINTS, cfg.icp.normal_neighbours):
            self._target = prepare_target(points, cfg.icp)
            self._target_s = t
