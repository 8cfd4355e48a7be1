"""Splitting CPU launches across threads.

A Warp launch on the CPU runs on one thread and releases the GIL, so independent ranges of a
launch can run on several threads at once. Their CPU "atomics" are plain read-modify-writes:
only split launches whose ranges write disjoint memory (or give each part its own output).
"""

from __future__ import annotations

import concurrent.futures
import os

import numpy as np

# Below this many items a launch is not worth splitting.
MIN_ITEMS_PER_PART = 2048

_executor: concurrent.futures.ThreadPoolExecutor | None = None


def num_parts(device, count: int) -> int:
    """How many parts a launch over `count` items is split into on `device`."""
    if device.is_cuda:
        return 1
    return int(max(1, min(os.cpu_count() or 1, 8, count // MIN_ITEMS_PER_PART)))


def split_launch(launch, count: int, parts: int) -> None:
    """Call launch(part, lo, hi) for `parts` contiguous ranges of [0, count), concurrently."""
    global _executor
    if count == 0:
        return
    if parts <= 1:
        launch(0, 0, count)
        return
    if _executor is None:
        _executor = concurrent.futures.ThreadPoolExecutor(os.cpu_count() or 1,
                                                          thread_name_prefix="vogjax")
    edges = np.linspace(0, count, parts + 1).astype(int)
    futures = [_executor.submit(launch, part, lo, hi)
               for part, (lo, hi) in enumerate(zip(edges[:-1], edges[1:]))]
    for future in futures:
        future.result()
