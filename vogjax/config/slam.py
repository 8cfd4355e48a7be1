"""Settings of the SLAM front end: ICP, the correlative search, loop-closure detection."""

from __future__ import annotations

import dataclasses

from vogjax.config.schema import Config, integer, non_negative, number, positive, section, text

ICP_METHODS = ("point_to_plane", "point_to_point_xyh")
ALIGNERS = ("correlative_icp",)  # vogjax.slam.loop_closure.ALIGNERS


@dataclasses.dataclass(frozen=True)
class IcpConfig(Config):
    """max_iterations; max_correspondence_m: pairs farther apart are outliers; tolerance: stop
    when an update moves less than this (rad and m); normal_neighbours: target points used to
    fit each normal; lambda_min: directions whose eigenvalue of J^T J is below lambda_min times
    the number of inliers are degenerate (per inlier, so the threshold does not depend on the
    cloud's size; a unit normal contributes at most 1 to a translation direction; above zero:
    a direction with no information at all must never count as constrained); min_inliers;
    free: the directions point-to-plane ICP solves for, "all" six or only the "translation"
    (the rotation held where it starts: when navigation knows it better than the clouds do).
    A translation-only pair that can only cycle stops before max_iterations, unconverged."""

    max_iterations: int = integer(50, low=1, high=10_000)
    max_correspondence_m: float = positive(1.0)
    tolerance: float = positive(1e-6)
    normal_neighbours: int = integer(10, low=3, high=1000)
    lambda_min: float = positive(0.01)
    min_inliers: int = integer(10, low=3)
    free: str = text("all", ("all", "translation"))


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
    drift sigmas of odometry; min_sigma_*: floors on the factor's sigmas. ICP's own covariance
    is overconfident: each submap is bent by the drift within it (0.17 m sigma over 20 s at the
    default rates), which ICP cannot see."""

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
    # at most 1e5 (m or rad): a sigma floor squared must stay a variance the pose graph takes (<= 1e12)
    min_sigma_rotation_rad: float = number(0.005, low=0, high=1e5)
    min_sigma_translation_m: float = number(0.2, low=0, high=1e5)
