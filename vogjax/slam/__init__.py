"""SLAM backend: GTSAM pose graph (iSAM2), ICP, loop-closure detection."""

from vogjax.config import CorrelativeConfig, IcpConfig, LoopClosureConfig, PoseGraphConfig
from vogjax.geometry import pose_deltas
from vogjax.slam.backend import ClosureCheck, PoseGraph
from vogjax.slam.correlative import CorrelativeMatch, correlative_xyh, correlative_xyh_batch
from vogjax.slam.icp import IcpResult, IcpTarget, icp, icp_batch, prepare_target
from vogjax.slam.loop_closure import LoopClosure, LoopClosureDetector, Rejection

__all__ = [
    "ClosureCheck",
    "CorrelativeConfig",
    "CorrelativeMatch",
    "IcpConfig",
    "IcpResult",
    "IcpTarget",
    "LoopClosure",
    "LoopClosureConfig",
    "LoopClosureDetector",
    "PoseGraph",
    "PoseGraphConfig",
    "Rejection",
    "correlative_xyh",
    "correlative_xyh_batch",
    "icp",
    "icp_batch",
    "pose_deltas",
    "prepare_target",
]
