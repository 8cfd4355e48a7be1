"""SLAM backend: GTSAM pose graph (iSAM2), ICP, loop-closure detection.

- `PoseGraph`: submap base poses on iSAM2, odometry factors from the navigation's drift, loop
  closures screened against the graph (`ClosureCheck`) and entered with a robust loss;
- `LoopClosureDetector`: candidate pairs of submaps, aligned and accepted or rejected
  (`LoopClosure`, `Rejection`);
- `correlative_xyh`: the x-y-yaw search over the navigation's drift that seeds ICP
  (`CorrelativeMatch`), and `self_score`, what a complete overlap scores;
- `ScanMatcher`: the odometry corrected by registering each scan to a local map of the last
  few seconds' scans (a lidar's own heading);
- `icp`: point-to-plane (degeneracy-aware) and 2D point-to-point ICP, batched (`IcpResult`,
  `IcpTarget`), its directions judged at the source's centre (`centre_adjoint`,
  `constrained_basis`).

Poses are (4, 4) rigid transforms named by their frames (``T_world_submap``, ``T_i_k``);
covariances and tangents follow GTSAM's Pose3 order, rotation then translation.
"""

from vogjax.config import CorrelativeConfig, IcpConfig, LoopClosureConfig, PoseGraphConfig, ScanMatchingConfig
from vogjax.geometry import pose_deltas
from vogjax.slam.backend import ClosureCheck, PoseGraph
from vogjax.slam.correlative import CorrelativeMatch, correlative_xyh, correlative_xyh_batch, self_score
from vogjax.slam.icp import IcpResult, IcpTarget, centre_adjoint, constrained_basis, icp, icp_batch, prepare_target
from vogjax.slam.loop_closure import LoopClosure, LoopClosureDetector, Rejection
from vogjax.slam.odometry import ScanMatcher

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
    "ScanMatcher",
    "ScanMatchingConfig",
    "centre_adjoint",
    "constrained_basis",
    "correlative_xyh",
    "correlative_xyh_batch",
    "icp",
    "icp_batch",
    "pose_deltas",
    "prepare_target",
    "self_score",
]
