"""vogjax: GPU/JAX-accelerated batch occupancy mapping for SLAM-corrected robots."""

from vogjax.config import CrmConfig, MapConfig, NavNoise, PipelineConfig, SonarConfig
from vogjax.maps import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    ConfidenceMap,
    GlobalMap,
    RaycastResult,
    Submap,
    UpdateReport,
    VogMap,
    VoxelMap,
)


def _installed_version() -> str:
    # the version lives in pyproject.toml only: read from the installed package's metadata
    from importlib import metadata

    try:
        return metadata.version("vogjax")
    except metadata.PackageNotFoundError:  # run from a source folder without being installed
        return "0+unknown"


__version__ = _installed_version()

_SUBPACKAGES = (
    "config",
    "devices",
    "geometry",
    "io",
    "kernels",
    "maps",
    "pipeline",
    "planner",
    "report",
    "scenes",
    "sensors",
    "sim",
    "slam",
)


def __getattr__(name):
    # vj.slam, vj.sim, vj.pipeline, vj.planner, ...: imported on first use (GTSAM, MJX and h5py are heavy)
    if name in _SUBPACKAGES:
        import importlib

        return importlib.import_module(f"vogjax.{name}")
    raise AttributeError(f"module 'vogjax' has no attribute {name!r}")


__all__ = [
    "FREE",
    "OCCUPIED",
    "UNKNOWN",
    "ConfidenceMap",
    "CrmConfig",
    "GlobalMap",
    "MapConfig",
    "NavNoise",
    "PipelineConfig",
    "RaycastResult",
    "SonarConfig",
    "Submap",
    "UpdateReport",
    "VogMap",
    "VoxelMap",
    "__version__",
]
