"""Warp kernels of vogjax, one module per family: hashing, traversal, integration, queries.

Kernels take the map's arrays and write their outputs last; the Python classes in `vogjax`
own the arrays and launch them.
"""

from . import hashing, integration, queries, traversal

__all__ = ["hashing", "integration", "queries", "traversal"]
