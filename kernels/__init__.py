"""Warp kernels of vogjax, one module per family: hashing, traversal, integration, queries,
fixed_point and submap_view (shared by the two maps over submaps), accumulation (global map),
virtual (virtual map), ranging (simulated range sensors), ground_truth (scene labels),
registration (the SLAM front end: correlative scores, ICP's nearest neighbours).

Kernels take the map's arrays and write their outputs last; the Python classes in `vogjax`
own the arrays and launch them.
"""

from . import (accumulation, fixed_point, ground_truth, hashing, integration, queries, ranging, registration,
               submap_view, traversal, virtual)

__all__ = ["accumulation", "fixed_point", "ground_truth", "hashing", "integration", "queries", "ranging",
           "registration", "submap_view", "traversal", "virtual"]
