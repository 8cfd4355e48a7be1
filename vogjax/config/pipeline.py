"""Settings of batch reprocessing (`vogjax.pipeline`) and of `vogjax map` (the job)."""

from __future__ import annotations

import dataclasses

from vogjax.config.maps import MapConfig
from vogjax.config.schema import Config, flag, integer, non_negative, number, positive, section, text
from vogjax.config.sensing import NavNoise
from vogjax.config.slam import LoopClosureConfig, PoseGraphConfig


@dataclasses.dataclass(frozen=True)
class TimingConfig(Config):
    """Timing probes taken while a run is mapped (Sodhi et al., Figs. 8 and 9): after every
    `every_submaps` finished submaps (0: never) and after the last, a full merge of every
    submap so far (what a full-merge baseline redoes at a loop closure) and one query of
    `rays` planner rays of `ray_length_m` on the global and on the virtual map. Probe time is
    kept out of the pipeline's own timings."""

    every_submaps: int = integer(10, low=0)
    rays: int = integer(100_000, low=1, high=10_000_000)
    ray_length_m: float = positive(4.0)


@dataclasses.dataclass(frozen=True)
class PipelineConfig(Config):
    """scans_per_submap: cut a submap every this many scans (100 in Ho, 200 in Sodhi), or
    None ("covariance" in a settings file) to cut by Eq. 2: when the x, y or yaw variance
    accumulated since its base pose would exceed max_xy_variance_m2 / max_yaw_variance_rad2.
    eps_rot, eps_trans, eps_cov: Algorithm 1's thresholds (GlobalMap.update_poses); eps_move_m:
    ours, a submap is re-applied only if that moves some voxel of it by more than this (0: off,
    as in the paper); 0.05 m (half a voxel, also in the `paper` preset) bounds the updates at no
    measurable cost in AUC (see the README's paper protocol).
    batch_scans: scans read and integrated per step. standard_map: also build the
    navigation-only map (the no-SLAM baseline); confidence_map: and a confidence-rich map of
    the same scans (`vj.ConfidenceMap`, about six times the standard map's integration time).
    slam_thread: "on": batch reprocessing (`pipeline.run`, `vogjax map`) runs each submap's SLAM
    step on a second thread while the next scans are integrated (`Mapper(overlap=True)`), the
    same results bit for bit; "off": every step in order on one thread; "auto" (default): on
    when the maps run on a CUDA GPU (their kernels then need no CPU core), off on the CPU, where
    on the shared 2-core machine the two threads only contended (docs/benchmarks/slam.md)."""

    map: MapConfig = section(MapConfig())
    nav_noise: NavNoise = section(NavNoise())
    loop_closure: LoopClosureConfig = section(LoopClosureConfig())
    pose_graph: PoseGraphConfig = section(PoseGraphConfig())
    timing: TimingConfig = section(TimingConfig())
    scans_per_submap: int | None = integer(100, low=2, none_spelled="covariance")
    max_xy_variance_m2: float = positive(0.0276)  # 20 s of the paper's drift
    max_yaw_variance_rad2: float = positive(2e-6)
    eps_rot: float = non_negative(1e-2)
    eps_trans: float = non_negative(2e-3)
    eps_cov: float | str = number("auto", low=0, options=("auto",))
    eps_move_m: float = non_negative(0.05)
    batch_scans: int = integer(200, low=1)
    standard_map: bool = flag(True)
    confidence_map: bool = flag(False)
    slam_thread: str = text("auto", ("auto", "on", "off"))

    @classmethod
    def paper(cls, **changes) -> PipelineConfig:
        """Sodhi et al. IV-C: 200 scans per submap, `MapConfig.paper()` (hit/miss 0.75/0.2,
        thresholds 0.7/0.3, no clamping), eps_rot 1e-2 rad and eps_trans 2e-3 m, eps_cov the
        largest uncertainty among the first ten submaps; with our eps_move_m kept at its
        default (half a voxel), which bounds the online map's updates the paper's thresholds
        alone do not. `paper(eps_move_m=0.0)` is Algorithm 1 to the letter."""
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
    """surface_points: samples of the true surface for the reconstruction RMSE."""

    surface_points: int = integer(50_000, low=1, high=10_000_000)


@dataclasses.dataclass(frozen=True)
class JobConfig(Config):
    """Everything `vogjax map` reads from its settings file: tables [map], [nav_noise],
    [loop_closure] (with [loop_closure.icp], [loop_closure.correlative]), [pose_graph], [timing]
    and [pipeline] set `pipeline`; [report] sets `report`."""

    pipeline: PipelineConfig = section(PipelineConfig(), flatten=True)
    report: ReportConfig = section(ReportConfig())

    @classmethod
    def preset(cls, name: str | None) -> JobConfig:
        """The defaults (None or "default") or a named preset ("paper": `PipelineConfig.paper()`)."""
        if name in (None, "default"):
            return cls()
        if name == "paper":
            return cls(pipeline=PipelineConfig.paper())
        raise ValueError(f"preset must be one of {', '.join(PRESETS)}, got {name!r}")


PRESETS = ("default", "paper")
