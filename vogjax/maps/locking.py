"""A fair readers-writer lock: queries share the map, updates have it to themselves, and both
are served in the order they arrive."""

from __future__ import annotations

import collections
import contextlib
import threading


class ReadWriteLock:
    """Many readers at once, or one writer, granted first come, first served: a reader waits
    only for writers that asked before it, a writer for everyone who asked before it. So a
    stream of queries cannot starve an update, and back-to-back updates cannot starve queries
    (readers arriving together between two updates go in together). Reading is reentrant: a
    thread that already reads is let in again at once (queued behind a waiting writer, it would
    wait for itself). A thread that writes must not take the lock again."""

    def __init__(self):
        self._condition = threading.Condition()
        self._readers = 0
        self._writing = False
        self._queue: collections.deque = collections.deque()  # [kind, granted] in arrival order
        self._held = threading.local()  # .reads: how many reads this thread holds

    def _grant(self) -> None:
        """Admit waiting requests from the head of the queue (called with the condition held)."""
        granted = False
        while self._queue and not self._writing:
            request = self._queue[0]
            if request[0] == "read":
                self._readers += 1
            elif self._readers == 0:
                self._writing = True
            else:
                break
            request[1] = True
            self._queue.popleft()
            granted = True
        if granted:
            self._condition.notify_all()

    def _acquire(self, kind: str) -> None:
        with self._condition:
            if kind == "read" and getattr(self._held, "reads", 0):
                self._readers += 1  # already reading: no writer can be in, nothing to wait for
                self._held.reads += 1
                return
            request = [kind, False]
            self._queue.append(request)
            self._grant()
            try:
                while not request[1]:
                    self._condition.wait()
            except BaseException:  # interrupted while waiting: leave the queue as if never asked
                if request[1]:
                    self._release_locked(kind)
                else:
                    self._queue.remove(request)
                    self._grant()
                raise
            if kind == "read":
                self._held.reads = 1

    def _release(self, kind: str) -> None:
        with self._condition:
            if kind == "read":
                self._held.reads -= 1
            self._release_locked(kind)

    def _release_locked(self, kind: str) -> None:
        if kind == "read":
            self._readers -= 1
        else:
            self._writing = False
        self._grant()

    @contextlib.contextmanager
    def reading(self):
        self._acquire("read")
        try:
            yield
        finally:
            self._release("read")

    @contextlib.contextmanager
    def writing(self):
        self._acquire("write")
        try:
            yield
        finally:
            self._release("write")
