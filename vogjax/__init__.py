"""vogjax: GPU/JAX-accelerated batch occupancy mapping for SLAM-corrected robots."""

from vogjax.blockmap import FREE, OCCUPIED, UNKNOWN, RaycastResult
from vogjax.config import MapConfig, NavNoise, SonarConfig
from vogjax.globalmap import GlobalMap, UpdateReport
from vogjax.submaps import Submap, VogMap
from vogjax.voxelmap import VoxelMap

__version__ = "0.1.0"

__all__ = [
    "FREE",
    "OCCUPIED",
    "UNKNOWN",
    "GlobalMap",
    "MapConfig",
    "NavNoise",
    "RaycastResult",
    "SonarConfig",
    "Submap",
    "UpdateReport",
    "VogMap",
    "VoxelMap",
    "__version__",
]
