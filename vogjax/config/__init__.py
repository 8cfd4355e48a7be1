"""Every setting of vogjax, declared and checked one way (`schema`), loadable from TOML.

vj.MapConfig(voxel_size=0.05)
vj.config.JobConfig.from_toml("settings.toml")
"""

from vogjax.config.crm import CrmConfig
from vogjax.config.lidar import LidarConfig
from vogjax.config.maps import MapConfig, logodds
from vogjax.config.pipeline import PRESETS, JobConfig, PipelineConfig, ReportConfig, TimingConfig
from vogjax.config.point_cloud import PointCloudConfig
from vogjax.config.schema import Config, Rule
from vogjax.config.sensing import NavNoise, SonarConfig
from vogjax.config.sim import ControllerConfig
from vogjax.config.slam import CorrelativeConfig, IcpConfig, LoopClosureConfig, PoseGraphConfig, ScanMatchingConfig

__all__ = [
    "Config",
    "ControllerConfig",
    "CorrelativeConfig",
    "CrmConfig",
    "IcpConfig",
    "JobConfig",
    "LidarConfig",
    "LoopClosureConfig",
    "MapConfig",
    "NavNoise",
    "PRESETS",
    "PipelineConfig",
    "PoseGraphConfig",
    "ScanMatchingConfig",
    "PointCloudConfig",
    "ReportConfig",
    "Rule",
    "SonarConfig",
    "TimingConfig",
    "logodds",
]
