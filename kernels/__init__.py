"""Warp kernels of vogjax, one module per family: hashing, traversal, integration, queries,
accumulation (global map), virtual (virtual map), ranging (simulated range
sensors), ground_truth (scene
labels).

Kernels take the map's arrays and write their outputs last; the Python classes in `vogjax`
own the arrays and launch them.
"""

from . import accumulation, ground_truth, hashing, integration, queries, ranging, traversal, virtual

__all__ = ["accumulation", "ground_truth", "hashing", "integration", "queries", "ranging", "traversal", "virtual"]
