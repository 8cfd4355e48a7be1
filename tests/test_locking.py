"""The map lock is fair: a continuous writer does not starve readers, nor readers a writer."""

import threading
import time

from vogjax.maps.locking import ReadWriteLock


def _run(lock, writes: int, reads: int, hold_s: float) -> dict:
    progress = {"writes": 0, "reads": 0, "writes_at_last_read": None, "reads_at_last_write": None}

    def writer():
        for _ in range(writes):
            with lock.writing():
                time.sleep(hold_s)
                progress["writes"] += 1
        progress["reads_at_last_write"] = progress["reads"]

    def reader():
        for _ in range(reads):
            with lock.reading():
                time.sleep(hold_s / 10)
                progress["reads"] += 1
        progress["writes_at_last_read"] = progress["writes"]

    threads = [threading.Thread(target=writer), threading.Thread(target=reader)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    return progress


def test_queries_progress_under_a_continuous_writer():
    # the writer asks again the moment it lets go; readers must still get their turns between
    progress = _run(ReadWriteLock(), writes=60, reads=10, hold_s=0.01)
    assert progress["reads"] == 10 and progress["writes"] == 60
    assert progress["writes_at_last_read"] <= 20  # each read waits for about one write, not for all


def test_an_update_progresses_under_continuous_queries():
    lock = ReadWriteLock()
    stop = threading.Event()
    reads = [0]

    def reader():
        while not stop.is_set():
            with lock.reading():
                time.sleep(0.002)
                reads[0] += 1

    readers = [threading.Thread(target=reader) for _ in range(3)]
    for t in readers:
        t.start()
    time.sleep(0.05)
    start = time.perf_counter()
    with lock.writing():  # gets in although readers keep coming
        waited = time.perf_counter() - start
        before = reads[0]
        time.sleep(0.02)
        assert reads[0] == before  # and has the map to itself
    stop.set()
    for t in readers:
        t.join()
    assert waited < 1.0


def test_a_reader_may_read_again_while_a_writer_waits():
    """A query that takes the lock again inside its read (a submap's bounds refreshed while its
    views are held) must not wait behind a writer that queued in between."""
    lock = ReadWriteLock()
    inner_done = threading.Event()
    writer_done = threading.Event()
    outer_has_lock = threading.Event()
    writer_started = threading.Event()

    def reader():
        with lock.reading():
            outer_has_lock.set()
            writer_started.wait(5)
            time.sleep(0.05)  # the writer is queued now
            with lock.reading():
                inner_done.set()

    def writer():
        outer_has_lock.wait(5)
        writer_started.set()
        with lock.writing():
            writer_done.set()

    threads = [threading.Thread(target=reader, daemon=True), threading.Thread(target=writer, daemon=True)]
    for t in threads:
        t.start()
    assert inner_done.wait(5), "the nested read waited behind the queued writer"
    assert writer_done.wait(5)


def test_an_interrupted_wait_leaves_the_lock_usable():
    lock = ReadWriteLock()
    holder_in, release = threading.Event(), threading.Event()

    def holder():
        with lock.writing():
            holder_in.set()
            release.wait(5)

    t = threading.Thread(target=holder, daemon=True)
    t.start()
    holder_in.wait(5)
    original = lock._condition.wait

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    lock._condition.wait = interrupted
    try:
        lock.reading().__enter__()
    except KeyboardInterrupt:
        pass
    lock._condition.wait = original
    release.set()
    t.join(5)
    wrote = threading.Event()

    def writer():
        with lock.writing():  # neither the abandoned read nor the finished write holds it
            wrote.set()

    threading.Thread(target=writer, daemon=True).start()
    assert wrote.wait(5), "an abandoned request still holds the lock"
