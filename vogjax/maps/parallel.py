"""Splitting CPU launches across threads, and mapping other GIL-free work over them.

A Warp launch on the CPU runs on one thread and releases the GIL, so independent ranges of a
launch can run on several threads at once. Their CPU "atomics" are plain read-modify-writes:
only split launches whose ranges write disjoint memory (or give each part its own output).
The same pool serves `ordered_map`: the loop-closure detector's FFTs and k-d tree queries
(which release the GIL too) while the map work waits for SLAM.
"""

from __future__ import annotations

import concurrent.futures
import os
import threading
from collections.abc import Iterator

import numpy as np

# Below this many items a launch is not worth splitting.
MIN_ITEMS_PER_PART = 2048


def usable_cores() -> int:
    """The CPUs this process may run on: its affinity where the system tells it (taskset and
    containers narrow it), else every CPU of the machine."""
    if hasattr(os, "process_cpu_count"):  # Python 3.13
        return os.process_cpu_count() or 1
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0)) or 1
    return os.cpu_count() or 1


# The most threads a launch is split across (asked once, not at every launch).
CPU_THREADS = min(usable_cores(), 8)

_executor: concurrent.futures.ThreadPoolExecutor | None = None
_executor_lock = threading.Lock()


def _pool() -> concurrent.futures.ThreadPoolExecutor:
    global _executor
    with _executor_lock:
        if _executor is None:
            _executor = concurrent.futures.ThreadPoolExecutor(usable_cores(), thread_name_prefix="vogjax")
        return _executor


def _forget_executor() -> None:
    # a forked child inherits the pool but not its threads (its launches would wait forever)
    global _executor, _executor_lock
    _executor, _executor_lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_executor)


def num_parts(device, count: int) -> int:
    """How many parts a launch over `count` items is split into on `device`."""
    if device.is_cuda:
        return 1
    return int(max(1, min(CPU_THREADS, count // MIN_ITEMS_PER_PART)))


def split_launch(launch, count: int, parts: int) -> None:
    """Call launch(part, lo, hi) for `parts` contiguous ranges of [0, count), concurrently."""
    if count == 0:
        return
    parts = max(parts, 1)
    edges = [count * part // parts for part in range(parts + 1)]  # integers: no float rounding
    _run(launch, [(part, lo, hi) for part, (lo, hi) in enumerate(zip(edges[:-1], edges[1:]))])


def launch_ranges(launch, ranges: list) -> None:
    """Call launch(part, lo, hi) for each (lo, hi) of `ranges`, concurrently."""
    _run(launch, [(part, int(lo), int(hi)) for part, (lo, hi) in enumerate(ranges) if hi > lo])


def _run(launch, ranges: list) -> None:
    """launch(part, lo, hi) for each range: the first on the calling thread, which would only wait
    otherwise (a hand-off to a pool thread and back costs about 0.1 ms a launch), the others on
    the pool. Every one has finished when this returns, also when one raised. Called from a pool
    thread (a part that splits again), every range runs on that thread: waiting there for parts
    queued behind busy workers could deadlock the pool."""
    if not ranges:
        return
    if len(ranges) == 1 or getattr(_worker, "active", False):
        for r in ranges:
            launch(*r)
        return
    futures = [_pool().submit(_on_worker, launch, r) for r in ranges[1:]]
    try:
        launch(*ranges[0])
    finally:
        concurrent.futures.wait(futures)  # no launch left running into arrays the caller drops
    for future in futures:
        future.result()


def ordered_map(function, items, threaded: bool = True) -> Iterator:
    """function(item) for each item, the results in order, on the pool's threads where the
    machine has more than one core, there are two items or more and `threaded` (the caller's
    judgement that an item is worth a hand-off to a thread, some tens of microseconds); on the
    calling thread otherwise, and from a pool thread (as `_run`). Each item computes as it would
    in a loop, so the results are a loop's, bit for bit."""
    items = list(items)
    if CPU_THREADS < 2 or len(items) < 2 or not threaded or getattr(_worker, "active", False):
        return map(function, items)
    return _pool().map(lambda item: _on_worker(function, (item,)), items)


_worker = threading.local()


def _on_worker(launch, r: tuple):
    _worker.active = True
    try:
        return launch(*r)
    finally:
        _worker.active = False


def disjoint_order(spans: np.ndarray, parts: int) -> tuple[np.ndarray, list]:
    """Order items writing to the blocks spans[i] (lo, hi per axis: (N,2,2) for x and y) so that
    threads can write without atomics: returns (order (N,), phases), each phase a list of
    ranges of `order` run concurrently, the phases one after another. Phase 1 splits the items
    by x quantiles, keeping those that straddle a cut; phase 2 splits those by y; the few that
    straddle both cuts form the last phase, run by one thread."""
    index = np.arange(len(spans))
    order, phases = [], []
    for axis in range(2):
        lo, hi = spans[index, axis, 0], spans[index, axis, 1]
        cuts = np.quantile((lo + hi) / 2, np.arange(1, parts) / parts).astype(np.int64) if len(index) else []
        edges = np.concatenate([[np.iinfo(np.int64).min], cuts, [np.iinfo(np.int64).max]])
        part = np.searchsorted(edges, lo, side="right") - 1  # the part holding each item's lowest block
        inside = hi < edges[part + 1]
        ranges, start = [], len(np.concatenate(order)) if order else 0
        for p in range(parts):
            members = index[inside & (part == p)]
            order.append(members)
            ranges.append((start, start + len(members)))
            start += len(members)
        phases.append(ranges)
        index = index[~inside]
    order.append(index)
    total = len(spans) - len(index)
    phases.append([(total, len(spans))])
    return np.concatenate(order).astype(np.int64), phases
