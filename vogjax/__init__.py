"""vogjax: GPU/JAX-accelerated batch occupancy mapping for SLAM-corrected robots."""

from vogjax.blockmap import FREE, OCCUPIED, UNKNOWN, RaycastResult
from vogjax.config import MapConfig
from vogjax.voxelmap import VoxelMap

__version__ = "0.1.0"

__all__ = [
    "FREE",
    "OCCUPIED",
    "UNKNOWN",
    "MapConfig",
    "RaycastResult",
    "VoxelMap",
    "__version__",
]
