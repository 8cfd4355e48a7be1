"""Settings of SLAM: ICP, the correlative search, loop-closure detection, the pose graph."""

from __future__ import annotations

import dataclasses

from vogjax.config.schema import Config, flag, integer, non_negative, number, positive, section, text

ICP_METHODS = ("point_to_plane", "point_to_point_xyh")
ALIGNERS = ("correlative_icp",)  # vogjax.slam.loop_closure.ALIGNERS
ROBUST_LOSSES = ("none", "huber", "cauchy", "geman_mcclure", "dcs")  # GTSAM's noiseModel.mEstimator
CLOSURE_SCREENS = ("none", "graph")
OVERLAP_REFERENCES = ("absolute", "self")  # LoopClosureConfig.overlap_reference


@dataclasses.dataclass(frozen=True)
class IcpConfig(Config):
    """Settings of ICP (`vogjax.slam.icp`): when it stops, which pairs count, which directions it
    solves for and which count as constrained.

    These defaults are for ICP on its own; loop closure gives its ICP settings of its own
    (`LoopClosureConfig.icp`: max_correspondence_m 0.3 m, tolerance 1e-3, free "translation").

    `lambda_min` is per inlier, so the threshold does not depend on the cloud's size (a unit
    normal contributes at most 1 to a translation direction), and above zero: a direction with
    no information at all must never count as constrained. With `free` "translation", a pair
    that can only cycle stops before max_iterations, unconverged.

    Attributes
    ----------
    max_iterations : int
        Most iterations of one alignment.
    max_correspondence_m : float
        Pairs of points farther apart than this are outliers, metres.
    tolerance : float
        Stop when an update moves less than this: its rotation angle in rad plus its
        translation in m.
    normal_neighbours : int
        Target points used to fit each normal (the smallest principal axis of their scatter).
    lambda_min : float
        Directions whose eigenvalue of J^T J is below lambda_min times the number of inliers
        are degenerate: not solved for, and not in `IcpResult.basis`.
    min_inliers : int
        An alignment with fewer inliers stops, unconverged.
    free : str
        The directions point-to-plane ICP solves for: "all" six, "yaw" (the translation and the
        rotation about the source's z axis, pitch and roll held: where they are measured
        absolutely but the heading drifts), or only the "translation" (the rotation held where
        it starts: when navigation knows it better than the clouds do).

    Raises
    ------
    ValueError
        If a setting is out of its range.
    """

    max_iterations: int = integer(50, low=1, high=10_000)
    max_correspondence_m: float = positive(1.0)
    tolerance: float = positive(1e-6)
    normal_neighbours: int = integer(10, low=3, high=1000)
    lambda_min: float = positive(0.01)
    min_inliers: int = integer(10, low=3)
    free: str = text("all", ("all", "yaw", "translation"))


@dataclasses.dataclass(frozen=True)
class CorrelativeConfig(Config):
    """Settings of the correlative x-y-yaw search that seeds loop-closure ICP
    (`vogjax.slam.correlative_xyh`).

    Attributes
    ----------
    resolution_m : float
        Cell edge of the search grid, metres: x-y offsets are searched in whole cells.
    yaw_step_rad : float
        Step of the yaw grid, radians.
    blur_voxels : float
        Sigma of the Gaussian blur of the target's occupancy grid, in cells: tolerance to small
        distortions (0: no blur).
    exclusion_m : float
        The runner-up peak is the best one at least this far from the peak in x-y, metres.

    Raises
    ------
    ValueError
        If a setting is out of its range.
    """

    resolution_m: float = positive(0.1)
    yaw_step_rad: float = positive(0.005)
    blur_voxels: float = non_negative(1.0)
    exclusion_m: float = positive(0.5)


@dataclasses.dataclass(frozen=True)
class LoopClosureConfig(Config):
    """Settings of loop-closure detection (`vogjax.slam.LoopClosureDetector`): which pairs are
    aligned, how, which results are accepted, and the closure's covariance.

    A pair is accepted when the correlative peak overlaps enough and is unambiguous, ICP
    converges near it with a low fitness and enough of the source matched, and the result lies
    within the navigation's possible drift of odometry.

    The closure's covariance: ICP's own (fitness times the inverse of J^T J) is overconfident,
    each submap being bent by the drift within it (0.17 m sigma over 20 s at the default rates),
    which moves all its points together. `registration_sigma_m` models that: along each
    eigen-direction of J^T J with information lambda per inlier the closure's sigma is
    registration_sigma_m / sqrt(lambda) (0.025 m: the errors measured against the rigid truths
    on propeller surveys, 0.02-0.03 m times 1 / sqrt(lambda) across lambda = 0.005 to 1).
    Directions with less information than `min_information` per inlier are left to odometry
    with registration_sigma_m > 0; at 0 the factor keeps ICP's directions (`icp.lambda_min`).

    Attributes
    ----------
    aligner : str
        How a candidate pair is aligned: "correlative_icp", a correlative x-y-yaw search seeds
        ICP.
    method : str
        ICP variant: "point_to_plane" or "point_to_point_xyh" (`vogjax.slam.icp`).
    icp : IcpConfig
        ICP's settings; it starts at the correlative peak. By default it solves for the
        translation only and stops at 1 mm steps: on sonar swaths ICP's yaw is worse than the
        navigation's (1.3 against 0.6 degrees median on a propeller survey), and point-to-plane
        steps keep flipping correspondences below a millimetre.
    correlative : CorrelativeConfig
        The correlative search's settings.
    max_search_m : float
        Cap on the correlative search radius in x-y, metres (the radius is the navigation's
        drift bound, `drift_sigmas` sigmas, capped here).
    min_search_m : float
        With the pose graph's uncertainty of the pair (the pipeline's), the search looks
        `drift_sigmas` of the graph's sigmas around its estimate when that is narrower than the
        navigation's bound, but no narrower than this in x-y, metres (in yaw, when ICP solves
        it: no narrower than the turn that moves the source's farthest point this far). After
        the first loop the graph knows a pair's offset to decimetres where the navigation
        allows metres; a floor of twice `correlative.exclusion_m` leaves the ambiguity test a
        ring to find a runner-up in.
    min_overlap_score : float
        Least overlap: the correlative peak's score (the mean blurred occupancy under the source
        points), over the reference `overlap_reference` names.
    overlap_reference : str
        What the peak's score is measured against: "absolute" (the score as it is, the papers'
        gate on sonar swaths) or "self" (over the score the source cloud gets against itself,
        `vogjax.slam.correlative.self_score`: the share of a complete overlap reached, whatever
        the grid, the blur and the shape of the sensor's surfaces).
    max_ambiguity : float
        Most runner-up score (the best at least `correlative.exclusion_m` from the peak) over
        the peak's: repetitive structure matches in several places (1 lets every pair through).
    min_inlier_fraction : float
        ICP must match at least this share of the source cloud (0: no test).
    max_refinement_m : float
        ICP may move the peak's result at most this far in x-y, metres.
    min_points : int
        Both clouds need at least this many occupied voxels (and 3, ICP's least).
    min_separation : int
        Pairs are at least this many submaps apart (at least 1: a submap is not closed with
        itself): neighbours are tied by odometry already.
    max_candidates : int
        At most this many candidates are aligned, the earlier submaps nearest to k (aligning
        costs most of a submap's time).
    max_fitness_m2 : float
        Most ICP fitness (mean squared inlier distance) accepted, m^2.
    drift_sigmas : float
        Accept results within this many drift sigmas of odometry (also the search's radius in
        x-y, and in yaw when ICP solves for the yaw): in x-y the x and y drift over the time
        between the two submaps and, when ICP solves the yaw, the x-y error a drifting yaw
        leaves over the path between them ("drift"); in yaw, when ICP solves it, the yaw drift
        ("yaw drift").
    registration_voxel_m : float
        The submap clouds registered are the returns' means per voxel of this size, metres (0:
        the map's voxel size; a lidar's clouds are registered coarser than they are mapped).
    registration_sigma_m : float
        The closure's sigma along a direction of information lambda per inlier is
        registration_sigma_m / sqrt(lambda), metres (0.025 m: measured on propeller surveys;
        0: ICP's own covariance).
    min_information : float
        Directions with less information per inlier are left out of the factor, to odometry
        (at 0.05 their sigma would exceed 0.11 m; such closures were the wrong ones).
    min_sigma_rotation_rad : float
        Floor added to the factor's rotation sigmas, radians (it matters only for full
        six-direction factors).
    min_sigma_translation_m : float
        Floor added to the factor's translation sigmas, metres (0.2 m was the flat model before
        registration_sigma_m).

    Raises
    ------
    ValueError
        If a setting is out of its range.
    """

    aligner: str = text("correlative_icp", ALIGNERS)
    method: str = text("point_to_plane", ICP_METHODS)
    icp: IcpConfig = section(IcpConfig(max_correspondence_m=0.3, tolerance=1e-3, free="translation"))
    correlative: CorrelativeConfig = section(CorrelativeConfig())
    max_search_m: float = non_negative(4.0)
    min_search_m: float = non_negative(1.0)
    min_overlap_score: float = non_negative(0.3)
    overlap_reference: str = text("absolute", OVERLAP_REFERENCES)
    max_ambiguity: float = non_negative(1.0)
    min_inlier_fraction: float = number(0.0, low=0, high=1)
    max_refinement_m: float = non_negative(0.2)
    min_points: int = integer(50, low=0)
    min_separation: int = integer(2, low=1)
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
    """How loop closures enter the pose graph (`vogjax.slam.PoseGraph`): a screen, then a robust
    loss.

    The screen whitens a closure's error by its covariance plus the graph's own uncertainty of
    the relative pose (iSAM2's joint marginal of the two submaps). It refuses a wrong closure
    while the graph still knows better; one that came first, while nothing contradicted it, is
    left to the robust loss. iSAM2 weighs a robust factor where it linearises it and again only
    when it relinearises it, so a closure's loss starts as wide as the uncertainty it was
    screened with (`ClosureCheck.scale`): a right closure far from the estimate after a long
    loop keeps its weight. Calibrated closures (`LoopClosureConfig.registration_sigma_m`) lay
    within 3 sigmas of their rigid truths on the surveys measured, so a `robust_width` of 3
    leaves right ones near Gaussian. Measured (docs/benchmarks/slam.md): with 10% of the
    closures made wrong by 1-3 m and 5-20 degrees, the Gaussian graph's trajectory error grows
    several times over, this one's far less.

    Attributes
    ----------
    screen : str
        "graph": a closure enters only if its error at the current estimate, whitened by its
        covariance plus the graph's uncertainty of the relative pose, lies within
        `screen_sigmas`; "none": every closure enters.
    screen_sigmas : float
        The screen's bound: a chi-square bound over the directions the closure constrains, at
        the probability of this many sigmas of one normal variable (3: 0.9973).
    robust_loss : str
        The loss of every closure factor, GTSAM's `noiseModel.Robust` with the m-estimator
        named; "none": Gaussian, a wrong closure pulls with all its weight.
    robust_width : float
        The loss's parameter, in sigmas of the closure's whitened error (Huber's k, Cauchy's k,
        Geman-McClure's c; DCS gets its square as phi, its bound on the squared error); 3
        leaves calibrated closures near Gaussian.

    Raises
    ------
    ValueError
        If a setting is out of its range.
    """

    screen: str = text("graph", CLOSURE_SCREENS)
    screen_sigmas: float = number(3.0, low=0.5, high=100.0)
    robust_loss: str = text("cauchy", ROBUST_LOSSES)
    robust_width: float = number(3.0, low=0.1, high=1000.0)


@dataclasses.dataclass(frozen=True)
class ScanMatchingConfig(Config):
    """Scan matching over the recorded odometry (`vogjax.slam.ScanMatcher`): every `every_s`
    seconds a scan is registered by ICP to a local map of the scans registered over the last
    `window_s`, starting from the odometry's motion since the last registered scan; the scans in
    between keep that registration's correction of the odometry. A lidar's own geometry holds
    the heading far better than wheel odometry does (on the warehouse runs: 0.032-0.042 m against
    0.33-1.05 m rms of base-pose error, before any loop closure), and the first submap, which anchors the pose
    graph, is no longer bent by the odometry's first seconds of drift.

    Off by default and in the sonar preset (a profiling sonar's one fan holds too little to
    register scan against scan); on in the lidar preset.

    Attributes
    ----------
    enabled : bool
        Correct the odometry by scan matching before the scans reach the maps and the graph.
    every_s : float
        Seconds between registrations: the first scan in each slot of this length (counted
        from the run's first scan) is registered.
    window_s : float
        The local map holds the scans registered over the last this many seconds.
    refresh_s : float
        The local map's k-d tree and normals are rebuilt after every refresh_s / every_s
        (rounded, at least 1) scans that joined it.
    voxel_m : float
        Scans and the local map are registered as the means of their points per voxel of this
        size, metres.
    icp : IcpConfig
        ICP's settings; `free` follows the navigation noise as the loop closures' does. Pairs
        at most 0.5 m apart: with 1 m the registrations of a sparse 16-ring scan took in
        wrong pairs and stayed 5-7 cm off even with exact odometry (0.012-0.016 m at 0.4-0.5 m).

    Raises
    ------
    ValueError
        If a setting is out of its range.
    """

    enabled: bool = flag(False)
    every_s: float = positive(0.5)
    window_s: float = positive(10.0)
    refresh_s: float = positive(2.5)
    voxel_m: float = number(0.5, low=1e-3, high=1e3)
    icp: IcpConfig = section(IcpConfig(max_iterations=30, max_correspondence_m=0.5, tolerance=1e-4, free="yaw"))
