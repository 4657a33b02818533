# Fixed-rate tick source: a thread sleeps to absolute monotonic deadlines and wakes the event loop.
from __future__ import annotations

import asyncio
import threading
import time


class Metronome:
    """Delivers ticks at ``next += period`` deadlines to a coroutine waiting in :meth:`wait`.

    Sleeping in a thread with ``time.sleep`` is accurate to tens of microseconds, where the
    event loop's own timers round up to whole milliseconds. If the loop has not consumed the
    previous tick (it is blocked), the deadline is counted as missed instead of queued, so a
    stalled loop never receives a burst of stale ticks.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, period_s: float) -> None:
        self.loop = loop
        self.period_s = period_s
        self.missed = 0
        self._deadline = 0.0
        self._event = asyncio.Event()
        self._pending = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="metronome", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)

    async def wait(self) -> float:
        """Wait for the next tick; returns its deadline (monotonic seconds)."""
        await self._event.wait()
        self._event.clear()
        with self._lock:
            self._pending = False
            return self._deadline

    def _run(self) -> None:
        deadline = time.monotonic()
        while not self._stop.is_set():
            deadline += self.period_s
            now = time.monotonic()
            if deadline < now - self.period_s:  # fell far behind: skip, do not burst
                skipped = int((now - deadline) / self.period_s)
                self.missed += skipped
                deadline += skipped * self.period_s
            delay = deadline - time.monotonic()
            if delay > 0 and self._stop.wait(delay):
                return
            self._post(deadline)

    def _post(self, deadline: float) -> None:
        with self._lock:
            if self._pending:
                self.missed += 1
                return
            self._pending = True
            self._deadline = deadline
        try:
            self.loop.call_soon_threadsafe(self._event.set)
        except RuntimeError:  # loop closed
            self._stop.set()
