# The DDS writer thread: a bounded queue of samples to write, the oldest dropped when full.
from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable

log = logging.getLogger("arbiterd.ros2")

#: one job for the thread: serialise and write (runs in the thread, never on the event loop)
Job = Callable[[], None]


class Outlet:
    """Runs jobs in order in its own thread. :meth:`put` never blocks: with ``capacity``
    jobs waiting, the oldest is dropped (and counted). ``idle`` runs every ``idle_s``."""

    def __init__(self, capacity: int, idle: Job | None = None, idle_s: float = 0.25) -> None:
        self._jobs: deque[Job] = deque(maxlen=capacity)
        self._wake = threading.Event()
        self._stop = False
        self._idle = idle
        self._idle_s = idle_s
        self.dropped = 0
        self.written = 0
        self.failed = 0
        self._thread = threading.Thread(target=self._run, name="ros2-dds-writer", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def put(self, job: Job) -> None:
        if len(self._jobs) == self._jobs.maxlen:
            self.dropped += 1
        self._jobs.append(job)
        self._wake.set()

    def close(self, timeout_s: float = 2.0) -> None:
        self._stop = True
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def _run(self) -> None:
        next_idle = 0.0
        while not self._stop:
            self._wake.wait(self._idle_s)
            self._wake.clear()
            self._drain()
            if self._idle is not None and time.monotonic() >= next_idle:
                next_idle = time.monotonic() + self._idle_s
                self._call(self._idle)

    def _drain(self) -> None:
        while self._jobs and not self._stop:
            try:
                job = self._jobs.popleft()
            except IndexError:
                return
            if self._call(job):
                self.written += 1

    def _call(self, job: Job) -> bool:
        try:
            job()
        except Exception as exc:  # a bad sample or a DDS error must not end the thread
            self.failed += 1
            if self.failed <= 3 or self.failed % 1000 == 0:
                log.warning("ros2: a DDS write failed (%d so far): %r", self.failed, exc)
            return False
        return True


