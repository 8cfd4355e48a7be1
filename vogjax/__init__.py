"""vogjax: GPU/JAX-accelerated batch occupancy mapping for SLAM-corrected robots."""

from vogjax.blockmap import FREE, OCCUPIED, UNKNOWN, RaycastResult
from vogjax.config import MapConfig, NavNoise, SonarConfig
from vogjax.globalmap import GlobalMap, UpdateReport
from vogjax.submaps import Submap, VogMap
from vogjax.voxelmap import VoxelMap

__version__ = "0.1.0"

_SUBPACKAGES = ("eval", "io", "job", "pipeline", "scenes", "sim", "slam", "timing")


def __getattr__(name):
    # vj.slam, vj.sim, vj.pipeline, ...: imported on first use (GTSAM, MJX and h5py are heavy)
    if name in _SUBPACKAGES:
        import importlib

        return importlib.import_module(f"vogjax.{name}")
    raise AttributeError(f"module 'vogjax' has no attribute {name!r}")

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
