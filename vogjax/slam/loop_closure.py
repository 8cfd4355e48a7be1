"""Loop-closure detection between submaps (Ho, thesis 4.2, Algorithm 6 and its criteria).

For a new submap k, each earlier non-adjacent submap i with enough points whose box holds the
centroid of k's cloud (moved by the current relative estimate) is a candidate. Navigation can
have drifted metres between the two visits, beyond ICP's reach, so a correlative x-y-yaw search
over that drift (`correlative.py`) finds the best overlap first and ICP refines it. A candidate
is accepted when the overlap peak is high enough, ICP converged near the peak with a low
fitness, and the result lies within the navigation's possible drift of the odometry relative
pose. Degenerate alignments give partial factors over their well-conditioned directions; the
rest get full Pose3 factors.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from vogjax.config import LoopClosureConfig, NavNoise
from vogjax.geometry import inverse
from vogjax.slam.correlative import correlative_xyh
from vogjax.slam.icp import IcpResult, icp_batch


@dataclasses.dataclass(frozen=True)
class LoopClosure:
    """A constraint T_world_i^-1 T_world_k = T_i_k for PoseGraph.add_loop_closure."""

    i: int
    k: int
    T_i_k: np.ndarray
    covariance: np.ndarray  # (6,6), GTSAM order
    basis: np.ndarray | None  # (6,r) for a partial factor, None for a full one
    fitness: float
    num_inliers: int


@dataclasses.dataclass(frozen=True)
class Rejection:
    i: int
    k: int
    reason: str  # "overlap", "not converged", "fitness", "refinement", "drift"
    fitness: float  # NaN when ICP did not run ("overlap")
    deviation_m: float


class LoopClosureDetector:
    def __init__(self, noise: NavNoise | None = None, config: LoopClosureConfig | None = None):
        self.noise = noise or NavNoise()
        self.config = config or LoopClosureConfig()
        self.seconds = {"correlative_search": 0.0, "icp": 0.0}  # per phase, in the last detect call

    def candidates(self, k: int, clouds: list, bounds: list, poses: np.ndarray) -> list[int]:
        """Earlier submaps worth aligning with k (the thesis's precondition)."""
        cfg = self.config
        if len(clouds[k]) < cfg.min_points:
            return []
        centroid = np.append(clouds[k].mean(axis=0), 1.0)
        found, distances = [], []
        for i in range(0, k - cfg.min_separation + 1):
            if len(clouds[i]) < cfg.min_points or bounds[i] is None:
                continue
            in_i = (inverse(poses[i]) @ poses[k] @ centroid)[:3]
            if np.all(in_i >= bounds[i][0]) and np.all(in_i <= bounds[i][1]):
                found.append(i)
                distances.append(np.linalg.norm(in_i - clouds[i].mean(axis=0)))
        # the correlative search costs most of a submap's time: bound it by the best-placed few
        nearest = np.argsort(distances, kind="stable")[:cfg.max_candidates]
        return sorted(found[j] for j in nearest)

    def detect(self, k: int, clouds: list, bounds: list, poses: np.ndarray, nav_poses: np.ndarray,
               times_s: np.ndarray) -> tuple[list[LoopClosure], list[Rejection]]:
        """Loop closures of submap k with earlier submaps.

        clouds[i]: (N,3) occupied points in submap i's frame; bounds[i]: its (lo, hi) box or None;
        poses, nav_poses: (N,4,4) current estimates and navigation poses; times_s: (N,) times of
        the base poses, for the drift allowed between two submaps.
        """
        accepted, rejected = [], []
        self.seconds = dict.fromkeys(self.seconds, 0.0)
        found = self.candidates(k, clouds, bounds, poses)
        if not found:
            return accepted, rejected
        cfg = self.config
        start = time.perf_counter()
        seeds = {}
        for i in found:
            elapsed = abs(times_s[k] - times_s[i])
            seeds[i] = correlative_xyh(clouds[k], clouds[i], inverse(poses[i]) @ poses[k],
                                       min(self._drift_bound(elapsed), cfg.max_search_m),
                                       cfg.drift_sigmas * np.sqrt(self.noise.sigma2_yaw * elapsed), cfg.correlative)
        self.seconds["correlative_search"] = time.perf_counter() - start
        # too little overlap at the best offset: nothing for ICP to refine
        for i in [i for i in found if seeds[i].score < cfg.min_overlap_score]:
            rejected.append(Rejection(i, k, "overlap", np.nan, np.nan))
            found.remove(i)
        start = time.perf_counter()
        results = icp_batch([clouds[k]] * len(found), [clouds[i] for i in found],
                            [seeds[i].T_target_source for i in found], cfg.method, cfg.icp) if found else []
        self.seconds["icp"] = time.perf_counter() - start
        for i, result in zip(found, results):
            odometry = inverse(nav_poses[i]) @ nav_poses[k]
            deviation = float(np.linalg.norm((inverse(odometry) @ result.T_target_source)[:2, 3]))
            refinement = float(np.linalg.norm((inverse(seeds[i].T_target_source) @ result.T_target_source)[:2, 3]))
            reason = self._rejection(result, refinement, deviation, abs(times_s[k] - times_s[i]))
            if reason:
                rejected.append(Rejection(i, k, reason, result.fitness, deviation))
            else:
                accepted.append(self._closure(i, k, result))
        return accepted, rejected

    def _drift_bound(self, elapsed_s: float) -> float:
        """How far (m, x-y) navigation can plausibly drift in `elapsed_s`: drift_sigmas sigma."""
        return self.config.drift_sigmas * np.sqrt((self.noise.sigma2_x + self.noise.sigma2_y) * elapsed_s)

    def _rejection(self, result: IcpResult, refinement_m: float, deviation: float, elapsed_s: float) -> str | None:
        if not result.converged:
            return "not converged"
        if result.fitness > self.config.max_fitness_m2:
            return "fitness"
        if refinement_m > self.config.max_refinement_m:
            return "refinement"
        if deviation > self._drift_bound(elapsed_s):
            return "drift"
        return None

    def _closure(self, i: int, k: int, result: IcpResult) -> LoopClosure:
        cfg = self.config
        good = result.eigenvalues >= cfg.icp.lambda_min * result.num_inliers
        vectors = result.eigenvectors
        # sigma^2 H^-1 over the constrained directions; degenerate ones left unconstrained
        # (a partial factor drops them, a full factor never sees them: r = 6 then).
        variance = max(result.fitness, 1e-12)
        covariance = vectors[:, good] @ np.diag(variance / result.eigenvalues[good]) @ vectors[:, good].T
        floor = np.array([cfg.min_sigma_rotation_rad] * 3 + [cfg.min_sigma_translation_m] * 3) ** 2
        covariance = covariance + np.diag(floor)
        basis = None if good.all() else result.basis
        return LoopClosure(i, k, result.T_target_source, covariance, basis, result.fitness,
                           result.num_inliers)
