"""Warp kernels of vogjax, one module per family (18 modules; 14 define kernels, the other four
only Warp functions, structs and constants):

- hashing, traversal: the block hash table and exact voxel walks, shared by every family;
- integration, queries: the log-odds map's updates and look-ups and ray casts;
- levels: the coarse levels of a map (OctoMap's inner nodes: the maximum of the children);
- octree: decoding OctoMap's serialised trees (.bt, .ot, octomap_msgs);
- fixed_point and submap_view: shared by the two maps over submaps; accumulation (global map),
  virtual (virtual map);
- confidence, confidence_queries: the confidence-rich map's updates and queries;
- planner_maps (how the planner reads any map), view_gain, planner_collision: the planner;
- ranging (simulated range sensors), ground_truth (scene labels), registration (the SLAM front
  end: correlative scores, ICP's nearest neighbours).

Kernels take the map's arrays and write their outputs last; the Python classes in `vogjax`
own the arrays and launch them. The planner's three modules are imported on first use
(`vogjax.kernels.view_gain`, or `vogjax.planner`), the others with this package.
"""

from . import (
    accumulation,
    confidence,
    confidence_queries,
    fixed_point,
    ground_truth,
    hashing,
    integration,
    levels,
    octree,
    queries,
    ranging,
    registration,
    submap_view,
    traversal,
    virtual,
)

_LAZY = ("planner_collision", "planner_maps", "view_gain")


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "accumulation",
    "confidence",
    "confidence_queries",
    "fixed_point",
    "ground_truth",
    "hashing",
    "integration",
    "levels",
    "octree",
    "planner_collision",
    "planner_maps",
    "queries",
    "ranging",
    "registration",
    "submap_view",
    "traversal",
    "view_gain",
    "virtual",
]
