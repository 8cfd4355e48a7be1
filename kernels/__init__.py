"""Warp kernels of vogjax, one module per family: hashing, traversal, integration, queries,
accumulation (global map), virtual (virtual map), sonar (simulated ranges).

Kernels take the map's arrays and write their outputs last; the Python classes in `vogjax`
own the arrays and launch them.
"""

from . import accumulation, hashing, integration, queries, sonar, traversal, virtual

__all__ = ["accumulation", "hashing", "integration", "queries", "sonar", "traversal", "virtual"]
