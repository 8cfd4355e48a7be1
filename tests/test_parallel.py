"""Splitting CPU launches across threads: every item once, and nothing left running on return."""

import threading
import time

import pytest

from vogjax.maps import parallel


@pytest.mark.parametrize("count, parts", [(1, 1), (7, 3), (10, 4), (2048, 2), (5, 8), (100, 0)])
def test_split_launch_covers_every_item_once_in_contiguous_parts(count, parts):
    calls = []
    lock = threading.Lock()

    def launch(part, lo, hi):
        with lock:
            calls.append((part, lo, hi, threading.current_thread()))

    parallel.split_launch(launch, count, parts)
    calls.sort()
    covered = [i for _, lo, hi, _ in calls for i in range(lo, hi)]
    assert covered == list(range(count))
    assert [c[0] for c in calls] == list(range(max(parts, 1)))
    assert calls[0][3] is threading.current_thread()  # the first part runs on the caller's thread


def test_a_failing_part_is_raised_after_every_other_part_has_finished():
    finished = []

    def launch(part, lo, hi):
        if part == 0:
            raise RuntimeError("part 0 failed")
        time.sleep(0.05)
        finished.append(part)

    with pytest.raises(RuntimeError, match="part 0"):
        parallel.launch_ranges(launch, [(0, 1), (1, 2), (2, 3)])
    assert sorted(finished) == [1, 2]


def test_a_failing_pool_part_is_raised_once_all_have_finished():
    finished = []

    def launch(part, lo, hi):
        if part == 1:
            raise ValueError("part 1 failed")
        time.sleep(0.05 * part)
        finished.append(part)

    with pytest.raises(ValueError, match="part 1"):
        parallel.launch_ranges(launch, [(0, 1), (1, 2), (2, 3)])
    assert sorted(finished) == [0, 2]


def test_a_part_that_splits_again_runs_its_parts_without_deadlocking_the_pool():
    """Every pool thread busy with an outer part that splits again: the inner parts run on the
    threads that asked for them (queued behind the busy workers they would wait forever)."""
    outer = max(2, parallel.CPU_THREADS + 1)
    seen = []
    lock = threading.Lock()

    def inner(part, lo, hi):
        with lock:
            seen.append((lo, hi))

    def outer_part(part, lo, hi):
        time.sleep(0.02)  # keep every worker busy at once
        parallel.split_launch(inner, 8, 4)

    done = threading.Event()
    worker = threading.Thread(target=lambda: (parallel.split_launch(outer_part, outer, outer), done.set()), daemon=True)
    worker.start()
    assert done.wait(timeout=30), "nested split launches deadlocked"
    assert sorted(seen) == sorted([(2 * i, 2 * i + 2) for i in range(4)] * outer)


def _covered_in_child(count: int) -> tuple:
    covered = []
    lock = threading.Lock()

    def launch(part, lo, hi):
        with lock:
            covered.extend(range(lo, hi))

    parallel.split_launch(launch, count, 4)
    return sorted(covered), list(parallel.ordered_map(abs, range(-count, 0)))


# the child runs plain Python threads, none of JAX's, which the warning is about
@pytest.mark.filterwarnings("ignore:os.fork\\(\\) was called:RuntimeWarning")
def test_a_forked_child_splits_launches_on_threads_of_its_own():
    """A parent's launch threads do not survive a fork: a child (multiprocessing's default on
    Linux) splits its launches and maps its work on a pool of its own instead of waiting on dead
    threads."""
    import multiprocessing
    import sys

    if sys.platform == "win32":
        pytest.skip("no fork")
    expected = (list(range(100)), list(range(100, 0, -1)))
    assert _covered_in_child(100) == expected  # the parent's pool exists now
    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.apply_async(_covered_in_child, (100,)).get(timeout=60) == expected


def test_ordered_map_gives_a_loops_results_in_order_and_runs_on_the_pool_when_asked(monkeypatch):
    monkeypatch.setattr(parallel, "CPU_THREADS", 2)
    items = list(range(40))
    for threaded in (True, False):
        where = []

        def square(x, where=where):
            time.sleep(0.001 * (x % 3))  # finishing out of order
            where.append(threading.current_thread() is threading.main_thread())
            return x * x

        assert list(parallel.ordered_map(square, items, threaded)) == [x * x for x in items]
        assert (not any(where)) if threaded else all(where)
