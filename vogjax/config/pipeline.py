"""Settings of batch reprocessing (`vogjax.pipeline`) and of `vogjax map` (the job)."""

from __future__ import annotations

import dataclasses
from typing import Any

from vogjax.config.maps import MapConfig
from vogjax.config.schema import Config, flag, integer, non_negative, number, positive, section, text
from vogjax.config.sensing import NavNoise
from vogjax.config.slam import LoopClosureConfig, PoseGraphConfig, ScanMatchingConfig


@dataclasses.dataclass(frozen=True)
class TimingConfig(Config):
    """Settings of the timing probes taken while a run is mapped (Sodhi et al., Figs. 8 and 9).

    After every `every_submaps` finished submaps and after the last, a probe times a full merge
    of every submap so far (what a full-merge baseline redoes at a loop closure) and one query of
    `rays` planner rays of `ray_length_m` on the global and on the virtual map. Probe time is
    kept out of the pipeline's own timings.

    Attributes
    ----------
    every_submaps : int
        Probe after every this many finished submaps (and after the last); 0: never.
    rays : int
        Planner rays per query probe (the papers' 100k rays per planning iteration).
    ray_length_m : float
        Length of each probe ray, metres.
    """

    every_submaps: int = integer(10, low=0)
    rays: int = integer(100_000, low=1, high=10_000_000)
    ray_length_m: float = positive(4.0)


@dataclasses.dataclass(frozen=True)
class PipelineConfig(Config):
    """Settings of batch reprocessing: scans to submaps, SLAM and the global map (`vj.pipeline`).

    Submaps are cut by a fixed scan count or by Eq. 2 of Sodhi et al.; loop closures update the
    global map by Algorithm 1 with the thresholds `eps_rot`, `eps_trans`, `eps_cov` (see
    `GlobalMap.update_poses`) and our `eps_move_m`. `PipelineConfig.paper()` gives the paper's
    settings.

    Attributes
    ----------
    map : MapConfig
        The occupancy maps' settings (submaps, global map and the standard map).
    nav_noise : NavNoise
        The navigation's drift, for the odometry factors and for cutting submaps by Eq. 2.
    loop_closure : LoopClosureConfig
        Loop-closure detection and registration.
    pose_graph : PoseGraphConfig
        How closures enter the pose graph: the screen against the graph's own uncertainty and
        the robust loss.
    scan_matching : ScanMatchingConfig
        Scan matching over the recorded odometry (off by default; on in the lidar preset).
    timing : TimingConfig
        The timing probes taken while mapping.
    scans_per_submap : int or None
        Cut a submap every this many scans (100 in Ho, 200 in Sodhi), or None ("covariance" in a
        settings file) to cut by Eq. 2: when the x, y or yaw variance accumulated since its base
        pose would exceed `max_xy_variance_m2` / `max_yaw_variance_rad2`.
    max_xy_variance_m2 : float
        Eq. 2's bound on the x and y variance accumulated since a submap's base pose, m^2 (the
        default is 20 s of the paper's drift); used when `scans_per_submap` is None.
    max_yaw_variance_rad2 : float
        Eq. 2's bound on the yaw variance accumulated since a submap's base pose, rad^2; used
        when `scans_per_submap` is None.
    eps_rot : float
        Algorithm 1: a submap has moved if its pose rotated by more than this, radians.
    eps_trans : float
        Algorithm 1: a submap has moved if its pose translated by more than this, metres.
    eps_cov : float or str
        Algorithm 1: a submap is uncertain if the 95% x-y-yaw confidence volume of its marginal
        exceeds this, now or when last applied; "auto" takes the largest volume among the first
        ten submaps, as the paper does.
    eps_move_m : float
        Ours: a moved submap is re-applied only if the move shifts some corner of its observed box
        by more than this, metres (0: off, as in the paper). 0.05 m (half a voxel, also in the
        `paper` preset) bounds the updates at no measurable cost in AUC (docs/benchmarks/paper.md).
    batch_scans : int
        Scans read and integrated per step.
    standard_map : bool
        Also build the navigation-only map (the no-SLAM baseline).
    confidence_map : bool
        Also build a confidence-rich map of the same scans (`vj.ConfidenceMap`, about six times
        the standard map's integration time).
    slam_thread : str
        "on": batch reprocessing (`pipeline.run`, `vogjax map`) runs each submap's SLAM step on
        a second thread while the next scans are integrated (`Mapper(overlap=True)`), the same
        results bit for bit; "off": every step in order on one thread; "auto": on where a second
        core can take it, the maps on a CUDA GPU (their kernels then need no CPU core) or a CPU
        of two or more cores (on two: the pilings and LiDAR runs 10-11% faster, the propeller
        run's 2% slower; docs/benchmarks/slam.md), off on one core.
    """

    map: MapConfig = section(MapConfig())
    nav_noise: NavNoise = section(NavNoise())
    loop_closure: LoopClosureConfig = section(LoopClosureConfig())
    pose_graph: PoseGraphConfig = section(PoseGraphConfig())
    scan_matching: ScanMatchingConfig = section(ScanMatchingConfig())
    timing: TimingConfig = section(TimingConfig())
    scans_per_submap: int | None = integer(100, low=2, none_spelled="covariance")
    max_xy_variance_m2: float = positive(0.0276)  # 20 s of the paper's drift
    max_yaw_variance_rad2: float = positive(2e-6)
    eps_rot: float = non_negative(1e-2, doc="in rad")
    eps_trans: float = non_negative(2e-3, doc="in m")
    eps_cov: float | str = number("auto", low=0, options=("auto",))
    eps_move_m: float = non_negative(0.05)
    batch_scans: int = integer(200, low=1)
    standard_map: bool = flag(True)
    confidence_map: bool = flag(False)
    slam_thread: str = text("auto", ("auto", "on", "off"))

    @classmethod
    def paper(cls, **changes: Any) -> PipelineConfig:
        """The settings of Sodhi et al. IV-C.

        200 scans per submap, `MapConfig.paper()` (hit/miss 0.75/0.2, thresholds 0.7/0.3, no
        clamping), eps_rot 1e-2 rad and eps_trans 2e-3 m, eps_cov the largest uncertainty among
        the first ten submaps; with our eps_move_m kept at its default (half a voxel), which
        bounds the online map's updates the paper's thresholds alone do not.
        ``paper(eps_move_m=0.0)`` is Algorithm 1 to the letter.

        Parameters
        ----------
        **changes
            Settings that replace the paper's.

        Returns
        -------
        PipelineConfig
            The paper's settings with `changes` applied.
        """
        return cls(
            **{
                "map": MapConfig.paper(),
                "scans_per_submap": 200,
                "eps_rot": 1e-2,
                "eps_trans": 2e-3,
                "eps_cov": "auto",
                **changes,
            }
        )


@dataclasses.dataclass(frozen=True)
class ReportConfig(Config):
    """Settings of the `vogjax map` job's report.

    Attributes
    ----------
    surface_points : int
        Points sampled on the true surface for the reconstruction RMSE.
    """

    surface_points: int = integer(50_000, low=3, high=10_000_000)  # registering needs 3


@dataclasses.dataclass(frozen=True)
class JobConfig(Config):
    """Everything `vogjax map` reads from its settings file.

    The tables ``[map]``, ``[nav_noise]``, ``[loop_closure]`` (with ``[loop_closure.icp]``,
    ``[loop_closure.correlative]``), ``[pose_graph]``, ``[scan_matching]`` (with
    ``[scan_matching.icp]``), ``[timing]`` and ``[pipeline]`` set
    `pipeline`; ``[report]`` sets `report`.

    Attributes
    ----------
    pipeline : PipelineConfig
        The mapper's settings (a flattened section: its plain settings in ``[pipeline]``).
    report : ReportConfig
        The report's settings.

    Examples
    --------
    >>> JobConfig.from_document({"map": {"voxel_size": 0.05}}).pipeline.map.voxel_size
    0.05
    """

    pipeline: PipelineConfig = section(PipelineConfig(), flatten=True)
    report: ReportConfig = section(ReportConfig())

    @classmethod
    def preset(cls, name: str | None) -> JobConfig:
        """The defaults or a named preset.

        Parameters
        ----------
        name : str or None
            None or "default": the defaults; "paper": `PipelineConfig.paper()`.

        Returns
        -------
        JobConfig
            The preset's settings.

        Raises
        ------
        ValueError
            If `name` is not one of `PRESETS`.
        """
        if name in (None, "default"):
            return cls()
        if name == "paper":
            return cls(pipeline=PipelineConfig.paper())
        raise ValueError(f"preset must be one of {', '.join(PRESETS)}, got {name!r}")


PRESETS = ("default", "paper")
