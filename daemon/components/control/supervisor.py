# Stall supervisor: a thread that zeroes the wheels when the control tick stops running.
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from drivers import MotorDriver

log = logging.getLogger("arbiterd.control")

#: while stalled, how often a failed emergency stop is tried again, s
RETRY_S = 0.05


class StallSupervisor:
    """Watches the control tick from outside the event loop.

    The tick calls :meth:`beat`. When no beat came for ``stall_stop_s``, the thread calls
    ``driver.emergency_stop()`` (the driver's thread-safe path, which needs no event loop),
    logs once, counts, and latches: :meth:`take_stop` then answers True once, so the loop,
    when it runs again, can forget every command it had and wait for a fresh one. One stall
    stops the wheels once; a failed emergency stop is retried while the stall lasts.

    While the wheels were last told zero there is nothing to stop, and the thread sleeps
    until the loop says it wrote a speed that turns a wheel (:meth:`turning`): an idle robot's
    supervisor never wakes.
    """

    def __init__(self, driver: MotorDriver, stall_stop_s: float,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.driver = driver
        self.stall_stop_s = stall_stop_s
        self.clock = clock
        self.stall_stops = 0
        self.failed_stops = 0
        self.longest_stall_s = 0.0
        self.last_stall_s = 0.0
        self._lock = threading.Lock()
        self._last_beat = clock()
        #: the loop has ticked since start(): before the first tick nothing drives the wheels,
        #: and the start-up is no stall (longest_stall_ms is the longest time between ticks)
        self._ticking = True
        self._stopped_beat: float | None = None  # the beat after which the wheels were zeroed
        #: the wheels were zeroed behind the loop's back and the loop has not taken it yet
        #: (read without the lock: :meth:`take_stop` takes it under the lock)
        self.latched = False
        self._halt = threading.Event()
        self._thread: threading.Thread | None = None
        #: set while the wheels may turn (the thread watches the tick); cleared at rest
        self._watching = threading.Event()
        self._watched = False  # the loop's view of it: set() only on a change

    @property
    def enabled(self) -> bool:
        return self.stall_stop_s > 0

    # -- lifecycle ----------------------------------------------------------------------------

    def start(self) -> None:
        if not self.enabled:
            log.warning("[control] stall_stop_s = 0: the stall supervisor is DISABLED; a "
                        "blocked event loop leaves the wheels turning")
            return
        with self._lock:
            self._last_beat = self.clock()
            self._ticking = False
        self._halt.clear()
        self._watched = True
        self._watching.set()
        self._thread = threading.Thread(target=self._run, name="stall-supervisor", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._halt.set()
        self._watching.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    # -- the event loop's side ----------------------------------------------------------------

    def beat(self) -> None:
        """The control tick ran (called on the event loop, every tick). No lock: the beat is
        written before ``_ticking``, and :meth:`check` reads them the other way round."""
        now = self.clock()
        if self._ticking:
            gap = now - self._last_beat
            if gap > self.longest_stall_s:
                self.longest_stall_s = gap
            self._last_beat = now
        else:
            self._last_beat = now
            self._ticking = True

    def turning(self) -> None:
        """The loop wrote a speed that turns a wheel (called after every such write): the
        thread watches the tick again if it slept at rest."""
        if not self._watched:
            self._watched = True
            self._watching.set()

    def take_stop(self) -> bool:
        """True once after the wheels were zeroed behind the loop's back."""
        if not self.latched:  # no lock while nothing happened (a latch
            return False       # set just after this read is taken at the next step)
        with self._lock:
            latched, self.latched = self.latched, False
        return latched

    # -- the thread's side --------------------------------------------------------------------

    def _run(self) -> None:
        while not self._halt.is_set():
            if self._at_rest():
                self._watched = False
                self._watching.clear()
                if self._at_rest():  # again: a write that came between is not missed
                    self._watching.wait()
                    continue
            if self._halt.wait(self.check()):
                return

    def _at_rest(self) -> bool:
        """The wheels were last told zero: a stall now would stop nothing."""
        left, right = self.driver.last_command
        return left == 0.0 and right == 0.0

    def check(self) -> float:
        """Stop the wheels if the tick is overdue; seconds until the next check is due."""
        now = self.clock()
        with self._lock:
            if not self._ticking:
                return self.stall_stop_s
            last_beat = self._last_beat
            handled = self._stopped_beat == last_beat
        overdue = now - last_beat - self.stall_stop_s
        if overdue < 0:
            return -overdue
        if handled:
            return self.stall_stop_s
        return self._stop(last_beat, now)

    def _stop(self, last_beat: float, now: float) -> float:
        if not self.driver.emergency_stop():
            self.failed_stops += 1
            if self.failed_stops == 1 or self.failed_stops % 100 == 0:
                log.error("control tick stalled for %.0f ms; the emergency stop did not reach "
                          "the driver (%s), retrying", (now - last_beat) * 1e3,
                          self.driver.last_emergency_error or "driver not open")
            return RETRY_S
        with self._lock:
            self._stopped_beat = last_beat
            self.latched = True
        self.stall_stops += 1
        self.last_stall_s = now - last_beat
        log.error("control tick stalled for %.0f ms (event loop blocked?): wheels zeroed "
                  "through the driver's emergency path; they stay still until a fresh command",
                  (now - last_beat) * 1e3)
        return self.stall_stop_s

    # -- reporting ----------------------------------------------------------------------------

    def stalled(self) -> bool:
        return self.enabled and self._ticking and \
            self.clock() - self._last_beat > self.stall_stop_s

    def health(self) -> dict[str, Any]:
        return {
            "stall_stop_s": self.stall_stop_s,
            "stalled": self.stalled(),
            "stall_stops": self.stall_stops,
            "stall_stop_failures": self.failed_stops,
            "longest_stall_ms": round(self.longest_stall_s * 1e3, 1),
            "last_stall_ms": round(self.last_stall_s * 1e3, 1),
        }
