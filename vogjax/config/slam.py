"""Settings of SLAM: ICP, the correlative search, loop-closure detection, the pose graph."""

from __future__ import annotations

import dataclasses

from vogjax.config.schema import Config, integer, non_negative, number, positive, section, text

ICP_METHODS = ("point_to_plane", "point_to_point_xyh")
ALIGNERS = ("correlative_icp",)  # vogjax.slam.loop_closure.ALIGNERS
ROBUST_LOSSES = ("none", "huber", "cauchy", "geman_mcclure", "dcs")  # GTSAM's noiseModel.mEstimator
CLOSURE_SCREENS = ("none", "graph")


@dataclasses.dataclass(frozen=True)
class IcpConfig(Config):
    """max_iterations; max_correspondence_m: pairs farther apart are outliers; tolerance: stop
    when an update moves less than this (rad and m); normal_neighbours: target points used to
    fit each normal; lambda_min: directions whose eigenvalue of J^T J is below lambda_min times
    the number of inliers are degenerate (per inlier, so the threshold does not depend on the
    cloud's size; a unit normal contributes at most 1 to a translation direction; above zero:
    a direction with no information at all must never count as constrained); min_inliers;
    free: the directions point-to-plane ICP solves for, "all" six, "yaw" (the translation and
    the rotation about the source's z axis: pitch and roll held, where they are measured
    absolutely but the heading drifts) or only the "translation" (the rotation held where it
    starts: when navigation knows it better than the clouds do).
    A translation-only pair that can only cycle stops before max_iterations, unconverged."""

    max_iterations: int = integer(50, low=1, high=10_000)
    max_correspondence_m: float = positive(1.0)
    tolerance: float = positive(1e-6)
    normal_neighbours: int = integer(10, low=3, high=1000)
    lambda_min: float = positive(0.01)
    min_inliers: int = integer(10, low=3)
    free: str = text("all", ("all", "yaw", "translation"))


@dataclasses.dataclass(frozen=True)
class CorrelativeConfig(Config):
    """resolution_m of the search grid; yaw_step_rad; blur_voxels: Gaussian blur of the target,
    tolerance to small distortions; exclusion_m: the runner-up peak is the best one at least
    this far away."""

    resolution_m: float = positive(0.1)
    yaw_step_rad: float = positive(0.005)
    blur_voxels: float = non_negative(1.0)
    exclusion_m: float = positive(0.5)


@dataclasses.dataclass(frozen=True)
class LoopClosureConfig(Config):
    """aligner: how a candidate pair is aligned (`correlative_icp`: a correlative x-y-yaw search
    seeds ICP); method: ICP variant; icp: ICP settings (it starts at the correlative peak; by
    default it solves for translation only and stops at 1 mm steps: on sonar swaths ICP's yaw
    is worse than the navigation's, 1.3 against 0.6 degrees median on a propeller survey, and
    point-to-plane steps keep flipping correspondences below a millimetre);
    correlative; max_search_m: the correlative search radius, the drift bound capped here;
    min_overlap_score: the correlative peak's mean blurred occupancy; max_ambiguity: the best
    score at least `correlative.exclusion_m` away from the peak, over the peak's, at most this
    (repetitive structure matches in several places); min_inlier_fraction: ICP must match this
    share of the source cloud; max_refinement_m: ICP may
    move the peak's result this far in x-y; min_points: both clouds need this many occupied
    voxels; min_separation: |i - k| at least this (neighbours are tied by odometry already);
    max_candidates: the earlier submaps nearest to k are aligned, at most this many;
    max_fitness_m2: mean squared inlier distance; drift_sigmas: accept results within this many
    drift sigmas of odometry (in x-y: the x and y drift over the time between the two submaps
    and, when ICP solves the yaw, the x-y error a drifting yaw leaves over the path between
    them; in yaw, when ICP solves it: the yaw drift); registration_voxel_m: the submap clouds
    registered are the returns' means per voxel of this size (0: the map's voxel size; a
    lidar's clouds are registered coarser than they are mapped).
    The closure's covariance: ICP's own (fitness times the inverse of J^T J) is overconfident,
    each submap being bent by the drift within it (0.17 m sigma over 20 s at the default rates),
    which moves all its points together. registration_sigma_m models that: along each
    eigen-direction of J^T J with information lambda per inlier the closure's sigma is
    registration_sigma_m / sqrt(lambda) (0.025 m: the errors measured against the rigid truths
    on propeller surveys, 0.02-0.03 m times 1 / sqrt(lambda) across lambda = 0.005 to 1);
    min_information: directions with less information per inlier than this are left out of
    the factor (to odometry): at 0.05 their sigma would exceed 0.11 m, and such closures were
    the wrong ones; it applies with registration_sigma_m > 0 (at 0 the factor keeps ICP's
    directions, icp.lambda_min). min_sigma_*: floors added to the factor's sigmas (0.2 m in
    translation was the flat model before registration_sigma_m; rotation matters only for
    full six-direction factors)."""

    aligner: str = text("correlative_icp", ALIGNERS)
    method: str = text("point_to_plane", ICP_METHODS)
    icp: IcpConfig = section(IcpConfig(max_correspondence_m=0.3, tolerance=1e-3, free="translation"))
    correlative: CorrelativeConfig = section(CorrelativeConfig())
    max_search_m: float = non_negative(4.0)
    min_overlap_score: float = non_negative(0.3)
    max_ambiguity: float = non_negative(1.0)
    min_inlier_fraction: float = number(0.0, low=0, high=1)
    max_refinement_m: float = non_negative(0.2)
    min_points: int = integer(50, low=0)
    min_separation: int = integer(2, low=0)
    max_candidates: int = integer(4, low=0)
    max_fitness_m2: float = non_negative(0.02)
    drift_sigmas: float = non_negative(3.0)
    registration_voxel_m: float = number(0.0, low=0, high=1e3)
    registration_sigma_m: float = number(0.025, low=0, high=1e3)
    min_information: float = number(0.05, low=0, high=1)
    # at most 1e5 (m or rad): a sigma floor squared must stay a variance the pose graph takes (<= 1e12)
    min_sigma_rotation_rad: float = number(0.005, low=0, high=1e5)
    min_sigma_translation_m: float = number(0.0, low=0, high=1e5)


@dataclasses.dataclass(frozen=True)
class PoseGraphConfig(Config):
    """How loop closures enter the pose graph (`vogjax.slam.PoseGraph`).

    screen: "graph" tests each closure against the graph before it enters: its error at the
    current estimate, whitened by the closure's covariance plus the graph's own uncertainty of
    the relative pose (iSAM2's joint marginal of the two submaps), must lie within
    `screen_sigmas` (a chi-square bound over the directions the closure constrains, at the
    probability of that many sigmas of one normal variable); "none" lets every closure in. A
    wrong closure is refused while the graph still knows better; one that came first, while
    nothing contradicted it, is left to the robust loss.
    robust_loss: the loss of every closure factor, GTSAM's `noiseModel.Robust` with the
    m-estimator named ("none": Gaussian, a wrong closure pulls with all its weight); robust_width:
    its parameter, in sigmas of the closure's whitened error (Huber's k, Cauchy's k,
    Geman-McClure's c; DCS gets its square as phi, its bound on the squared error). Calibrated
    closures (`LoopClosureConfig.registration_sigma_m`) lay within 3 sigmas of their rigid
    truths on the surveys measured, so a width of 3 leaves right ones near Gaussian. iSAM2
    weighs a robust factor where it linearises it and again only when it relinearises it, so a
    closure's loss starts as wide as the uncertainty it was screened with (`ClosureCheck.scale`):
    a right closure far from the estimate after a long loop keeps its weight.
    Measured (docs/benchmarks/slam.md): with 10% of the closures made wrong by 1-3 m and 5-20
    degrees, the Gaussian graph's trajectory error grows several times over, this one's far less."""

    screen: str = text("graph", CLOSURE_SCREENS)
    screen_sigmas: float = number(3.0, low=0.5, high=100.0)
    robust_loss: str = text("cauchy", ROBUST_LOSSES)
    robust_width: float = number(3.0, low=0.1, high=1000.0)
