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
