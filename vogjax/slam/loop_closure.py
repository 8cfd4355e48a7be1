"""Loop-closure detection between submaps (Ho, thesis 4.2, Algorithm 6 and its criteria).

For a new submap k, each earlier non-adjacent submap i with enough points whose box holds the
centroid of k's cloud (moved by the current relative estimate) is a candidate; the nearest few
are aligned. The aligner (`ALIGNERS`, chosen by `LoopClosureConfig.aligner`; called with the
pairs, the settings, a dict for its phases' seconds, the detector's device and a dict it may
keep figures of clouds in from one call to the next) turns a candidate pair into an
`Alignment`; the default, `correlative_then_icp`, searches x, y and yaw over the navigation's
possible drift first (`correlative.py`: navigation can drift metres between two visits, beyond
ICP's reach) and refines the peak with ICP. The detector then accepts or
rejects each alignment by the same criteria whatever the aligner: enough overlap, an
unambiguous peak, ICP converged near it with a low fitness and enough of the source matched,
and a result within the navigation's possible drift of the odometry relative pose. Degenerate
alignments give partial factors over their well-conditioned directions; the rest get full
Pose3 factors.

A closure's covariance follows how well ICP's correspondences fix each direction: along an
eigen-direction of ICP's J^T J with information lambda per inlier, sigma =
registration_sigma_m / sqrt(lambda). On propeller surveys the closures' errors against the
rigid truths follow that law (their rms times sqrt(lambda) stays at 0.02-0.03 m from lambda =
0.005 to 1): a swath's residuals are not independent, a bend or an alias moves them together,
so a direction carries about one point's worth of information per unit of lambda, not one per
inlier. Directions below `min_information` per inlier are left to odometry: there the error is
too large to call the closure right or wrong.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt
import warp as wp

from vogjax import devices
from vogjax.config import LoopClosureConfig, NavNoise
from vogjax.geometry import inverse, log_se3, rigid_pose, rigid_poses, skew
from vogjax.slam.correlative import correlative_xyh, correlative_xyh_batch, self_score
from vogjax.slam.icp import IcpResult, IcpTarget, centre_adjoint, constrained_basis, icp_batch, prepare_target
from vogjax.validation import float_array, real_array


@dataclasses.dataclass(frozen=True)
class LoopClosure:
    """A constraint T_world_i^-1 T_world_k = T_i_k for PoseGraph.add_loop_closure, with the
    evidence it was accepted on.

    Attributes
    ----------
    i : int
        The earlier submap.
    k : int
        The later submap (the new one when detected).
    T_i_k : (4, 4) ndarray of float64
        Where submap k's base pose sits in submap i's frame (ICP's T_target_source, i the
        target).
    covariance : (6, 6) ndarray of float64
        The closure's covariance, GTSAM tangent order (rotation, then translation; rad and m).
    basis : (6, r) ndarray of float64 or None
        The directions a partial factor constrains (orthonormal columns); None for a full one.
    fitness : float
        ICP's mean squared inlier distance, m^2.
    num_inliers : int
        ICP's inliers (source points matched).
    overlap : float
        The aligner's overlap (the correlative peak's score, over its reference:
        `LoopClosureConfig.overlap_reference`); NaN when it has none.
    ambiguity : float
        Runner-up over peak score (0: unambiguous, 1: a tie); NaN when it has none.
    distance : float
        Mahalanobis distance from the graph's estimate at entry (NaN: not screened).
    centre : (3,) ndarray of float64
        Where in submap k's frame ICP judged the directions (`IcpResult.centre`: the cloud's
        centroid; zero with the rotation held), metres: `errors_at_centre` measures an error
        there.
    """

    i: int
    k: int
    T_i_k: npt.NDArray[np.float64]
    covariance: npt.NDArray[np.float64]
    basis: npt.NDArray[np.float64] | None
    fitness: float
    num_inliers: int
    overlap: float = np.nan
    ambiguity: float = np.nan
    distance: float = np.nan
    centre: npt.NDArray[np.float64] = dataclasses.field(default_factory=lambda: np.zeros(3))

    def errors_at_centre(self, T_i_k_true: npt.ArrayLike) -> tuple[float, float]:
        """The closure's error against a true relative pose, in what it constrains: the
        rotation (rad) and translation (m) of the error twist at `centre`, projected on the
        constrained directions there (where a turn and a shift are told apart, as ICP judged
        them; at the frame's origin a cloud 30 m off turns by a twist of rotation and 30 times
        as much translation).

        Parameters
        ----------
        T_i_k_true : (4, 4) array_like of float
            The true pose of submap k's base in submap i's frame.

        Returns
        -------
        rotation_rad, translation_m : float
            The norms of the constrained error's rotation and translation parts.

        Raises
        ------
        ValueError
            If `T_i_k_true` is not a rigid (4, 4) transform.
        """
        twist = log_se3(inverse(rigid_pose("T_i_k_true", T_i_k_true)) @ self.T_i_k)
        basis = np.eye(6) if self.basis is None else self.basis
        if self.centre.any():  # to the tangent at the centre, and the basis's span with it
            A = centre_adjoint(self.centre)
            twist = np.linalg.solve(A, twist)
            basis = np.linalg.qr(A.T @ basis)[0]
        constrained = basis @ (basis.T @ twist)
        return float(np.linalg.norm(constrained[:3])), float(np.linalg.norm(constrained[3:]))


# The self-scores a detector keeps for its aligner before it starts afresh (one per submap cloud)
MAX_KEPT_SCORES = 4096

REASONS = (
    "overlap",
    "ambiguous",
    "not converged",
    "fitness",
    "inliers",
    "refinement",
    "drift",
    "yaw drift",
    "information",
    "inconsistent",
)


@dataclasses.dataclass(frozen=True)
class Rejection:
    """A candidate pair that did not become a closure, and the figure that failed.

    Attributes
    ----------
    i : int
        The earlier submap.
    k : int
        The later submap (the new one when detected).
    reason : str
        The first test it failed (`REASONS`): "overlap" (correlative peak score), "ambiguous"
        (runner-up over peak), "not converged" (ICP), "fitness" (mean squared inlier distance),
        "inliers" (share of the source matched), "refinement" (how far ICP moved the peak),
        "drift" (x-y offset from the navigation), "yaw drift" (yaw offset from the navigation,
        when ICP solves the yaw), "information" (no direction holds `min_information` per
        inlier: nothing to constrain), "inconsistent" (the pose graph's screen).
    fitness : float
        ICP's mean squared inlier distance, m^2; NaN when ICP did not run.
    deviation_m : float
        x-y offset of ICP's result from the navigation's relative pose; NaN without ICP.
    value : float
        The figure that failed, in the test's units (score, ratio, m^2, share, m, rad, or the
        screen's Mahalanobis distance); NaN for "not converged".
    limit : float
        The bound it failed against.
    T_i_k : ndarray or None
        (4, 4) what the alignment found (None when ICP did not run), for scoring the verdict.
    """

    i: int
    k: int
    reason: str
    fitness: float
    deviation_m: float
    value: float = np.nan
    limit: float = np.nan
    T_i_k: npt.NDArray[np.float64] | None = None


@dataclasses.dataclass(frozen=True)
class Alignment:
    """What an aligner found for a pair: `icp` (None when it stopped before ICP), the seed it
    refined (T_i_k), its overlap score and ambiguity (NaN when it has none)."""

    icp: IcpResult | None
    T_seed: np.ndarray
    overlap: float
    ambiguity: float


def correlative_then_icp(
    pairs: list, config: LoopClosureConfig, seconds: dict, device=None, kept: dict | None = None
) -> list[Alignment]:
    """The default aligner. pairs: (source (N,3), target (an IcpTarget: submap i's cloud
    prepared once for every alignment it takes part in), T_init (4,4), radius_m,
    yaw_radius_rad) per candidate, source = submap k's cloud; `seconds` collects the time per
    phase; device: where the searches and ICP's neighbour queries run (None: on the host);
    `kept`: the clouds' self-scores by content, kept across calls (a submap's cloud is a target
    for many later ones)."""
    start = time.perf_counter()
    seeds = correlative_xyh_batch(
        [
            (source, target.points, T_init, radius_m, yaw_radius_rad)
            for source, target, T_init, radius_m, yaw_radius_rad in pairs
        ],
        config.correlative,
        device,
    )
    overlaps = _overlaps(pairs, seeds, config, kept)
    seconds["correlative_search"] = seconds.get("correlative_search", 0.0) + time.perf_counter() - start
    # too little overlap, or as good a match elsewhere: nothing trustworthy for ICP to refine
    refine = [
        n
        for n, seed in enumerate(seeds)
        if overlaps[n] >= config.min_overlap_score and seed.ratio <= config.max_ambiguity
    ]
    start = time.perf_counter()
    results = (
        icp_batch(
            [pairs[n][0] for n in refine],
            [pairs[n][1] for n in refine],
            [seeds[n].T_target_source for n in refine],
            config.method,
            config.icp,
            device,
        )
        if refine
        else []
    )
    seconds["icp"] = seconds.get("icp", 0.0) + time.perf_counter() - start
    refined = dict(zip(refine, results))
    return [Alignment(refined.get(n), seed.T_target_source, overlaps[n], seed.ratio) for n, seed in enumerate(seeds)]


def _overlaps(pairs: list, seeds: list, config: LoopClosureConfig, kept: dict | None = None) -> list[float]:
    """Each pair's overlap, the figure `min_overlap_score` gates: its peak's score as it is
    ("absolute"), or ("self") the larger of the shares of a complete overlap each cloud reaches
    on the other at the peak: the peak's score over the source's self-score, and the target's
    points scored on the source's field over the target's self-score (a short submap's cloud
    explains little of a long one's, however well the two match where they overlap). A cloud's
    self-score is looked up in `kept` by its values and the search's settings, and kept there."""
    if config.overlap_reference == "absolute":
        return [seed.score for seed in seeds]
    references = {} if kept is None else kept
    if len(references) > MAX_KEPT_SCORES:
        references.clear()

    def reference(cloud: np.ndarray) -> float:
        values = np.ascontiguousarray(cloud)
        key = (values.dtype.str, values.shape, hashlib.blake2b(values.tobytes(), digest_size=16).digest())
        key += (config.correlative,)
        if key not in references:
            references[key] = self_score(cloud, config.correlative)
        return references[key]

    out = []
    for (source, target, *_), seed in zip(pairs, seeds):
        forward = seed.score / reference(source)
        if seed.score == 0:  # no target point within reach: no overlap either way
            out.append(0.0)
            continue
        back = correlative_xyh(target.points, source, inverse(seed.T_target_source), 0.0, 0.0, config.correlative)
        out.append(max(forward, back.score / reference(target.points)))
    return out


ALIGNERS = {"correlative_icp": correlative_then_icp}


# A closure's least variance per direction: a 10 micrometre (or microradian) sigma, a hundred
# times the pose graph's least (`backend.MIN_VARIANCE`), so the covariance's round-off, and its
# move to GTSAM's tangent, stay clear of it
MIN_CLOSURE_VARIANCE = 1e-10


class LoopClosureDetector:
    """Finds loop closures of each new submap with earlier ones (Ho, thesis 4.2).

    Candidates (`candidates`) are aligned by the configured aligner (a correlative x-y-yaw
    search seeding ICP) and accepted or rejected by the criteria of `LoopClosureConfig`
    (`detect`). A submap's cloud is prepared for ICP once and kept while its points stay the
    same.

    Parameters
    ----------
    noise : NavNoise or None, optional
        The navigation's drift per second: how far the search looks and how far a result may
        lie from odometry (default: ``NavNoise()``).
    config : LoopClosureConfig or None, optional
        The search, ICP and acceptance settings (default: ``LoopClosureConfig()``).
    device : str or warp.Device or None, optional
        None aligns on the host (FFTs and k-d trees); a Warp device runs the correlative
        searches and ICP's neighbour queries there (`correlative_xyh_batch`, `icp_batch`), with
        the same closures but at near-exact ties.

    Attributes
    ----------
    noise : NavNoise
        The navigation's drift.
    config : LoopClosureConfig
        The settings.
    device : warp.Device or None
        Where alignments run (None: the host).
    seconds : dict of str to float
        Seconds per phase ("correlative_search", "icp") in the last `detect` call.

    Raises
    ------
    ValueError
        If `device` is not available.
    """

    def __init__(
        self,
        noise: NavNoise | None = None,
        config: LoopClosureConfig | None = None,
        device: str | wp.Device | None = None,
    ):
        self.noise = noise or NavNoise()
        self.config = config or LoopClosureConfig()
        self.device = None if device is None else devices.resolve(device)
        self.seconds = {"correlative_search": 0.0, "icp": 0.0}  # per phase, in the last detect call
        self._targets: dict[int, IcpTarget] = {}  # submap -> its cloud, prepared for ICP
        self._kept: dict = {}  # the aligner's figures of clouds, from one detect call to the next

    def _target(self, i: int, cloud: np.ndarray) -> IcpTarget:
        """Submap i's cloud prepared for ICP once: kept while the same values (compared point by
        point, cheap next to a tree and normals) come with the same ICP settings."""
        kept = self._targets.get(i)
        if (
            kept is None
            or kept.neighbours != self.config.icp.normal_neighbours
            or not np.array_equal(kept.points, cloud)
        ):
            start = time.perf_counter()
            kept = self._targets[i] = prepare_target(cloud, self.config.icp)
            self.seconds["icp"] += time.perf_counter() - start
        return kept

    def candidates(
        self,
        k: int,
        clouds: Sequence[npt.NDArray[np.floating]],
        bounds: Sequence[tuple[npt.NDArray[np.floating], npt.NDArray[np.floating]] | None],
        poses: npt.NDArray[np.floating],
    ) -> list[int]:
        """Earlier submaps worth aligning with k (the thesis's precondition).

        A candidate i is at least `min_separation` before k, both clouds hold at least
        `min_points` points (and 3 distinct ones), and i's box holds the centroid of k's cloud
        moved by the current relative estimate; of those, the `max_candidates` whose cloud
        centroid lies nearest it.

        Parameters
        ----------
        k : int
            The new submap's id.
        clouds : sequence of (N_i, 3) ndarray of float
            Each submap's occupied points, metres, in its own frame.
        bounds : sequence of tuple of two (3,) ndarray of float, or None
            Each submap's (lo, hi) box in its own frame (`Submap.bounds`), None when empty.
        poses : (N, 4, 4) ndarray of float
            The current estimates ``T_world_submap``.

        Returns
        -------
        list of int
            The candidates' ids, ascending.

        Raises
        ------
        ValueError
            As for `detect`, naming the argument.
        """
        clouds, poses = _checked_submaps(k, clouds, bounds, poses)
        return self._candidates(k, clouds, bounds, poses)

    def _candidates(self, k, clouds, bounds, poses) -> list[int]:
        cfg = self.config
        least = max(cfg.min_points, 3)  # ICP's least; fewer points are no cloud to align
        if len(clouds[k]) < least:
            return []
        _finite_cloud(k, clouds[k])
        if len(np.unique(clouds[k], axis=0)) < 3:  # one point repeated is no cloud either
            return []
        earlier = [i for i in range(0, k - cfg.min_separation + 1) if len(clouds[i]) >= least and bounds[i] is not None]
        if not earlier:
            return []
        lo, hi = _boxes(earlier, bounds)
        # k's centroid in each earlier frame, all at once: R_i^T (p - t_i)
        centroid = poses[k, :3, :3] @ clouds[k].mean(axis=0) + poses[k, :3, 3]
        in_frames = np.einsum("nji,nj->ni", poses[earlier, :3, :3], centroid - poses[earlier, :3, 3])
        found, distances = [], []
        for n in np.flatnonzero(np.all((in_frames >= lo) & (in_frames <= hi), axis=1)):
            i = earlier[n]
            _finite_cloud(i, clouds[i])
            try:  # its target, kept for the alignment: fewer than 3 distinct points make none
                self._target(i, clouds[i])
            except ValueError:
                continue
            found.append(i)
            distances.append(np.linalg.norm(in_frames[n] - clouds[i].mean(axis=0)))
        # aligning costs most of a submap's time: bound it by the best-placed few
        nearest = np.argsort(distances, kind="stable")[: cfg.max_candidates]
        return sorted(found[j] for j in nearest)

    def detect(
        self,
        k: int,
        clouds: Sequence[npt.NDArray[np.floating]],
        bounds: Sequence[tuple[npt.NDArray[np.floating], npt.NDArray[np.floating]] | None],
        poses: npt.NDArray[np.floating],
        nav_poses: npt.NDArray[np.floating],
        times_s: npt.NDArray[np.floating],
        relative_covariance: Callable[[int, int], npt.ArrayLike] | None = None,
    ) -> tuple[list[LoopClosure], list[Rejection]]:
        """Loop closures of submap k with earlier submaps.

        Each candidate is searched within the drift the navigation may have gathered between
        the two base poses (`drift_sigmas` sigmas, capped at `max_search_m`), or, given the
        pose graph's uncertainty of the pair, within `drift_sigmas` of its sigmas where that
        is narrower (no narrower than `min_search_m`), aligned, and accepted or rejected by
        the first test it fails (`Rejection.reason`).

        Parameters
        ----------
        k : int
            The new submap's id.
        clouds : sequence of (N_i, 3) ndarray of float
            clouds[i]: submap i's occupied points, metres, in its own frame.
        bounds : sequence of tuple of two (3,) ndarray of float, or None
            bounds[i]: its (lo, hi) box in its own frame, or None.
        poses : (N, 4, 4) ndarray of float
            Current estimates ``T_world_submap``.
        nav_poses : (N, 4, 4) ndarray of float
            Navigation base poses ``T_world_submap_nav``.
        times_s : (N,) ndarray of float
            Times of the base poses, seconds, increasing, for the drift allowed between two
            submaps.
        relative_covariance : callable or None, optional
            ``relative_covariance(i, k)``: the (6, 6) covariance of ``poses[i]^-1 poses[k]``
            in its right tangent, GTSAM order (`PoseGraph.relative_covariance`); None: the
            navigation's drift alone bounds the searches.

        Returns
        -------
        closures : list of LoopClosure
            The accepted closures, for `PoseGraph.add_loop_closure`.
        rejections : list of Rejection
            The candidates that failed, with the figure that failed.

        Raises
        ------
        ValueError
            Naming the argument, before any work: `k` not an id of `clouds`, `bounds`, `poses`,
            `nav_poses` or `times_s` not one per cloud, a cloud not (N, 3) real numbers (or,
            where it is used, with NaN or infinite values), a box it uses not (lo, hi) with
            lo <= hi, poses not rigid, or times not finite or not increasing; or, before any
            search, if `relative_covariance` returns no (6, 6) finite covariance.
        """
        clouds, poses = _checked_submaps(k, clouds, bounds, poses)
        nav_poses = rigid_poses("nav_poses", nav_poses, count=len(clouds))
        times_s = float_array("times_s", times_s, (len(clouds),), np.float64)
        if np.any(np.diff(times_s) <= 0):  # the drift between two submaps grows with their time apart
            raise ValueError("times_s must increase, one base pose after the other")
        accepted, rejected = [], []
        self.seconds = dict.fromkeys(self.seconds, 0.0)
        found = self._candidates(k, clouds, bounds, poses)
        if not found:
            return accepted, rejected
        cfg = self.config
        solves_yaw = cfg.icp.free != "translation"
        pairs, bounds_m = [], []
        for i in found:
            elapsed = abs(times_s[k] - times_s[i])
            # with ICP holding the rotation, the search takes the yaw from the estimate too
            yaw_radius = cfg.drift_sigmas * np.sqrt(self.noise.sigma2_yaw * elapsed) if solves_yaw else 0.0
            lever = _yaw_lever_m2(i, k, nav_poses, times_s) if solves_yaw else None
            bounds_m.append(self._drift_bound(elapsed, lever))
            T_init = inverse(poses[i]) @ poses[k]
            radius = min(bounds_m[-1], cfg.max_search_m)
            if relative_covariance is not None:  # where the graph knows the pair better
                covariance = _covariance_of(i, k, relative_covariance(i, k))
                radius, yaw_radius = self._graph_search(clouds[k], T_init, covariance, radius, yaw_radius)
            pairs.append((clouds[k], self._target(i, clouds[i]), T_init, radius, yaw_radius))
        alignments = ALIGNERS[cfg.aligner](pairs, cfg, self.seconds, self.device, self._kept)
        for i, alignment, bound in zip(found, alignments, bounds_m):
            odometry = inverse(nav_poses[i]) @ nav_poses[k]
            result = alignment.icp
            offset = None if result is None else inverse(odometry) @ result.T_target_source
            deviation = np.nan if offset is None else float(np.linalg.norm(offset[:2, 3]))
            yaw_bound = cfg.drift_sigmas * np.sqrt(self.noise.sigma2_yaw * abs(times_s[k] - times_s[i]))
            yaw = (np.nan, yaw_bound) if offset is None or not solves_yaw else (abs(_yaw_of(offset)), yaw_bound)
            failed = self._rejection(alignment, len(clouds[k]), deviation, bound, yaw)
            if failed:
                reason, value, limit = failed
                fitness, found_T = (np.nan, None) if result is None else (result.fitness, result.T_target_source)
                rejected.append(Rejection(i, k, reason, fitness, deviation, value, limit, found_T))
            else:
                accepted.append(self._closure(i, k, alignment))
        return accepted, rejected

    def _graph_search(
        self, source: np.ndarray, T_init: np.ndarray, covariance: np.ndarray, radius_m: float, yaw_radius_rad: float
    ) -> tuple[float, float]:
        """The search's x-y and yaw radii narrowed to `drift_sigmas` of the graph's sigmas of the
        pair, judged where the search turns the source (its centroid, moved into i's frame), no
        narrower than `min_search_m` (in yaw: its turn at the source's farthest point) and no
        wider than the navigation's bounds given."""
        cfg = self.config
        centroid = source.mean(axis=0)
        rotation = T_init[:3, :3]
        # under T_init Exp(xi), the centroid moves by rotation (-[centroid]x w + v)
        lever = rotation @ np.hstack([-skew(centroid), np.eye(3)])
        position = lever @ covariance @ lever.T
        sigma_xy = np.sqrt(max(float(np.linalg.eigvalsh(position[:2, :2]).max()), 0.0))
        radius = min(radius_m, max(cfg.drift_sigmas * sigma_xy, cfg.min_search_m))
        if yaw_radius_rad <= 0:
            return radius, yaw_radius_rad
        sigma_yaw = np.sqrt(max(float((rotation @ covariance[:3, :3] @ rotation.T)[2, 2]), 0.0))
        moved = source @ rotation.T
        reach = float(np.linalg.norm(moved[:, :2] - moved[:, :2].mean(axis=0), axis=1).max())
        floor = cfg.min_search_m / reach if reach > 0 else np.pi
        return radius, min(yaw_radius_rad, max(cfg.drift_sigmas * sigma_yaw, floor))

    def _drift_bound(self, elapsed_s: float, lever_m2: float | None = None) -> float:
        """How far (m, x-y) navigation can plausibly drift in `elapsed_s`: drift_sigmas sigma of
        the x and y drift, and with `lever_m2` (when ICP solves the yaw, so the yaw is taken
        to drift) of the x-y error the yaw drift leaves: sigma2_yaw times `lever_m2`."""
        variance = (self.noise.sigma2_x + self.noise.sigma2_y) * elapsed_s
        if lever_m2 is not None:
            variance = variance + self.noise.sigma2_yaw * lever_m2
        return self.config.drift_sigmas * np.sqrt(variance)

    def _rejection(
        self,
        alignment: Alignment,
        source_points: int,
        deviation: float,
        bound_m: float,
        yaw: tuple[float, float] = (np.nan, np.nan),
    ) -> tuple[str, float, float] | None:
        """(reason, the figure that failed, its bound) of the first test failed, or None; `yaw`:
        the result's yaw offset from the navigation and its bound (NaN: not tested)."""
        cfg, result = self.config, alignment.icp
        if alignment.overlap < cfg.min_overlap_score:
            return "overlap", alignment.overlap, cfg.min_overlap_score
        if alignment.ambiguity > cfg.max_ambiguity:
            return "ambiguous", alignment.ambiguity, cfg.max_ambiguity
        if result is None or not result.converged:
            return "not converged", np.nan, np.nan
        if result.fitness > cfg.max_fitness_m2:
            return "fitness", result.fitness, cfg.max_fitness_m2
        if result.num_inliers < cfg.min_inlier_fraction * source_points:
            return "inliers", result.num_inliers / source_points, cfg.min_inlier_fraction
        refinement = float(np.linalg.norm((inverse(alignment.T_seed) @ result.T_target_source)[:2, 3]))
        if refinement > cfg.max_refinement_m:
            return "refinement", refinement, cfg.max_refinement_m
        if deviation > bound_m:
            return "drift", deviation, bound_m
        if yaw[0] > yaw[1]:
            return "yaw drift", yaw[0], yaw[1]
        floor, good = self._constrained(result)
        if not good.any():  # a closure must constrain something: a factor of rank 0 is none
            return "information", float(result.eigenvalues.max()) / max(result.num_inliers, 1), floor
        return None

    def _constrained(self, result) -> tuple[float, np.ndarray]:
        """The information per inlier a direction needs, and which of ICP's eigen-directions
        hold it."""
        cfg = self.config
        floor = max(cfg.icp.lambda_min, cfg.min_information if cfg.registration_sigma_m > 0 else 0.0)
        return floor, result.eigenvalues >= floor * max(result.num_inliers, 1)

    def _closure(self, i: int, k: int, alignment: Alignment) -> LoopClosure:
        cfg, result = self.config, alignment.icp
        inliers = max(result.num_inliers, 1)
        _, good = self._constrained(result)
        vectors = result.eigenvectors
        # ICP's sigma^2 H^-1 (fitness as sigma^2) over the constrained directions (in the
        # tangent at the source's centre, as ICP's eigen-directions are), plus, with
        # registration_sigma_m, the misfit a bend or an alias moves all the swath's points by:
        # registration_sigma_m^2 / lambda per inlier. Directions left out are the partial
        # factor's to drop (a full factor never sees them: r = 6 then); they get a variance of
        # 1 so the matrix stays positive definite whatever the floors.
        values = result.eigenvalues[good]
        variance = max(result.fitness, 1e-12) / values + cfg.registration_sigma_m**2 * inliers / values
        covariance = vectors[:, good] @ np.diag(variance) @ vectors[:, good].T
        covariance = covariance + vectors[:, ~good] @ vectors[:, ~good].T
        floor = np.array([cfg.min_sigma_rotation_rad] * 3 + [cfg.min_sigma_translation_m] * 3) ** 2
        covariance = covariance + np.diag(floor)
        covariance = (covariance + covariance.T) / 2
        if result.centre.any():  # from the tangent at the cloud's centre, where ICP judged it, to GTSAM's
            A = centre_adjoint(result.centre)
            covariance = A @ covariance @ A.T
            covariance = (covariance + covariance.T) / 2
        # a perfect fit without registration_sigma_m or floors gave variances GTSAM cannot
        # invert, and the closure was refused: none below MIN_CLOSURE_VARIANCE
        least = np.linalg.eigvalsh(covariance)[0]
        if least < MIN_CLOSURE_VARIANCE:
            covariance = covariance + (MIN_CLOSURE_VARIANCE - least) * np.eye(6)
        basis = None if good.all() else constrained_basis(result, good)
        return LoopClosure(
            i,
            k,
            result.T_target_source,
            covariance,
            basis,
            result.fitness,
            result.num_inliers,
            alignment.overlap,
            alignment.ambiguity,
            centre=result.centre,
        )


def _checked_submaps(k, clouds, bounds, poses) -> tuple[list, np.ndarray]:
    """The detector's per-submap arguments, checked before any work (each cloud's values where
    it is used: the new one, and each candidate's)."""
    count = len(clouds)
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < count:
        raise ValueError(f"k must be a submap id, an integer in [0, {count}), got {k!r}")
    if len(bounds) != count:
        raise ValueError(f"bounds must have one entry per cloud ({count}), got {len(bounds)}")
    checked = []
    for i, cloud in enumerate(clouds):
        cloud = real_array(f"clouds[{i}]", cloud)
        if cloud.ndim != 2 or cloud.shape[1] != 3:
            raise ValueError(f"clouds[{i}] must have shape (N, 3), got {cloud.shape}")
        checked.append(cloud)
    return checked, rigid_poses("poses", poses, count=count)


def _covariance_of(i: int, k: int, value) -> np.ndarray:
    """What `relative_covariance(i, k)` returned, checked: a (6, 6) covariance of real, finite
    numbers with a non-negative diagonal."""
    try:
        covariance = real_array("relative_covariance", value)
    except ValueError:
        covariance = None
    if covariance is None or covariance.shape != (6, 6) or not np.all(np.isfinite(covariance)):
        raise ValueError(f"relative_covariance({i}, {k}) must return a (6, 6) array of finite numbers")
    if np.any(np.diag(covariance) < 0):
        raise ValueError(f"relative_covariance({i}, {k}) returned negative variances")
    return covariance


def _finite_cloud(i: int, cloud: np.ndarray) -> None:
    if not np.all(np.isfinite(cloud)):
        raise ValueError(f"clouds[{i}] contains NaN or infinite values")


def _boxes(ids: list[int], bounds) -> tuple[np.ndarray, np.ndarray]:
    """The (lo, hi) corners of the boxes `ids` names, (n, 3) each, checked as `_box` checks one
    (which names the first bad box when they do not stack)."""
    try:
        corners = np.array([bounds[i] for i in ids], dtype=np.float64)
    except (TypeError, ValueError):
        corners = None
    if (
        corners is None
        or corners.shape != (len(ids), 2, 3)
        or np.isnan(corners).any()
        or np.any(corners[:, 0] > corners[:, 1])
    ):
        corners = np.array([_box(i, bounds[i]) for i in ids])
    return corners[:, 0], corners[:, 1]


def _box(i: int, box) -> tuple[np.ndarray, np.ndarray]:
    try:
        lo, hi = (np.asarray(corner, dtype=np.float64) for corner in box)
    except (TypeError, ValueError):
        raise ValueError(f"bounds[{i}] must be None or a (lo, hi) pair of (3,) corners") from None
    if lo.shape != (3,) or hi.shape != (3,) or np.isnan(lo).any() or np.isnan(hi).any() or np.any(lo > hi):
        raise ValueError(f"bounds[{i}] must be None or a (lo, hi) pair of (3,) corners with lo <= hi")
    return lo, hi


def _yaw_of(T: np.ndarray) -> float:
    """Yaw of a rigid transform's rotation, radians."""
    return float(np.arctan2(T[1, 0], T[0, 0]))


def _yaw_lever_m2(i: int, k: int, nav_poses: np.ndarray, times_s: np.ndarray) -> float:
    """sum_j dt_j |p_k - p_j|^2 over the base poses j = i..k-1 between submaps i < k (their
    navigation positions p, base times t; dt_j = t_j+1 - t_j): the yaw drift of step j turns
    the path after it about p_j, so it moves submap k by its angle times |p_k - p_j|, and the
    x-y variance it leaves at k is sigma2_yaw times this sum (m^2 s)."""
    positions = nav_poses[i : k + 1, :2, 3]
    arms = np.sum((positions[-1] - positions[:-1]) ** 2, axis=1)
    return float(np.sum(np.diff(times_s[i : k + 1]) * arms))
