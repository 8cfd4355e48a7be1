"""The front end's second core: independent pieces of one registration step (the yaws of a
correlative search, the pairs of an ICP iteration) run on two threads at once.

NumPy's FFTs and SciPy's k-d tree queries release the GIL, so two of them run side by side. The
results come back in order and each piece computes as it would alone, so the bits are those of
a loop. On the CPU the map work and SLAM alternate (`PipelineConfig.slam_thread` "auto"), so
the other core is idle while SLAM runs.
"""

from __future__ import annotations

import concurrent.futures
import os
import threading
from collections.abc import Callable, Iterable, Iterator

THREADS = min(os.cpu_count() or 1, 2)

_pool: concurrent.futures.ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


def _forget_pool() -> None:
    # a forked child inherits the pool but not its threads: it makes its own
    global _pool, _pool_lock
    _pool, _pool_lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_pool)


def ordered_map(function: Callable, items: Iterable, parallel: bool = True) -> Iterator:
    """function(item) for each item, in order, two at a time where there are two cores, two
    items or more and `parallel` (the caller's judgement that each item is worth a hand-off to a
    thread, some tens of microseconds); one at a time otherwise."""
    items = list(items)
    if THREADS < 2 or len(items) < 2 or not parallel:
        return map(function, items)
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = concurrent.futures.ThreadPoolExecutor(THREADS, thread_name_prefix="vogjax-registration")
    return _pool.map(function, items)
