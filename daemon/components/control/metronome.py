# Fixed-rate tick source: a kernel timer the event loop watches, or a thread sleeping to deadlines.
from __future__ import annotations

import asyncio
import ctypes
import inspect
import logging
import math
import os
import sys
import threading
import time
from collections.abc import Awaitable, Callable

log = logging.getLogger("arbiterd.control")

#: what a metronome calls at each deadline: the tick, done when it returns None, else what is
#: left of it (it had to wait: for the step's lock, a driver write, a fault's handling)
OnTick = Callable[[float], Awaitable[None] | None]


class _Delivery:
    """The event loop's side that both metronomes share. A deadline goes to the tick at once,
    from the callback that noticed it (no task to wake: an idle robot's tick is one callback).
    Only the part of a tick that has to wait runs on the metronome's task; while it does, the
    next deadline waits for it, and any more are counted as missed, never queued."""

    def __init__(self, loop: asyncio.AbstractEventLoop, period_s: float) -> None:
        self.loop = loop
        self.period_s = period_s
        self.missed = 0
        self._on_tick: OnTick | None = None
        self._waiter: asyncio.Future[Awaitable[None]] | None = None  # the task's, while free
        self._queued: float | None = None  # a deadline waiting for the task

    async def run(self, on_tick: OnTick) -> None:
        """Call ``on_tick(deadline)`` at each deadline until cancelled; await what it leaves."""
        self._on_tick = on_tick
        waiter: asyncio.Future[Awaitable[None]] | None = None
        try:
            while True:
                self._waiter = waiter = self.loop.create_future()
                rest: Awaitable[None] | None = await waiter
                self._waiter = waiter = None
                while rest is not None:
                    await rest
                    deadline, self._queued = self._queued, None
                    rest = None if deadline is None else on_tick(deadline)
        finally:
            self._on_tick = self._waiter = None
            if waiter is not None and waiter.done() and not waiter.cancelled():
                left = waiter.result()  # handed over as the task was cancelled: never run
                if inspect.iscoroutine(left):
                    left.close()

    def _due(self, deadline: float, skipped: int) -> None:
        """``deadline`` came, and ``skipped`` earlier ones passed while the loop could not
        take them."""
        self.missed += skipped
        waiter, on_tick = self._waiter, self._on_tick
        if on_tick is None:
            return
        if waiter is None:  # the last tick is still waiting for something: this one waits
            if self._queued is not None:
                self.missed += 1
            self._queued = deadline
            return
        rest = on_tick(deadline)
        if rest is not None:
            self._waiter = None
            waiter.set_result(rest)


class Metronome(_Delivery):
    """Delivers ticks at ``next += period`` deadlines, from a thread.

    Sleeping in a thread with ``time.sleep`` is accurate to tens of microseconds, where the
    event loop's own timers round up to whole milliseconds. If the loop has not taken the
    previous deadline (it is blocked), the deadline is counted as missed instead of queued, so
    a stalled loop never receives a burst of stale ticks.

    This is the portable fallback of :class:`TimerMetronome` (see :func:`metronome`): it costs
    a thread that wakes every period and then wakes the event loop through its self-pipe.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, period_s: float) -> None:
        super().__init__(loop, period_s)
        self._posted: float | None = None  # a deadline on its way to the loop
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="metronome", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)

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
            posted, self._posted = self._posted, deadline
        if posted is not None:  # the loop has not taken the last one: it takes this instead
            self.missed += 1
            return
        try:
            self.loop.call_soon_threadsafe(self._take)
        except RuntimeError:  # loop closed
            self._stop.set()

    def _take(self) -> None:
        with self._lock:
            deadline, self._posted = self._posted, None
        if deadline is not None:
            self._due(deadline, 0)


class TimerMetronome(_Delivery):
    """The same ticks from a kernel timer (Linux ``timerfd`` on ``CLOCK_MONOTONIC``, the clock
    of ``time.monotonic``) that the event loop watches like a socket: the kernel wakes the loop
    at each absolute deadline (``next += period`` is the timer's own interval, so nothing
    drifts), to the tens of microseconds of a sleeping thread, without the thread. One wake-up
    per tick instead of two plus a self-pipe write and read: the idle daemon's largest cost.

    Expirations the loop could not take while it was blocked are counted as missed, never
    delivered late in a burst: after a stall the loop gets one tick, the latest deadline.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, period_s: float, timer: _Timer) -> None:
        super().__init__(loop, period_s)
        self._timer = timer
        self._next = 0.0  # the timer's next expiration

    def start(self) -> None:
        self._next = time.monotonic() + self.period_s
        self._timer.arm(self._next, self.period_s)
        self.loop.add_reader(self._timer.fd, self._on_timer)

    def stop(self) -> None:
        if self._timer.fd >= 0:
            self.loop.remove_reader(self._timer.fd)
            self._timer.close()

    def next_at(self, when: float) -> float:
        """The first deadline at or after ``when`` (monotonic seconds): a loop timer set for it
        fires in the event-loop wake-up of that tick (the kernel timer wakes the loop then)."""
        periods = max(0, math.ceil((when - self._next) / self.period_s))
        return self._next + periods * self.period_s

    def _on_timer(self) -> None:
        expirations = self._timer.read()
        if not expirations:
            return
        latest = self._next + (expirations - 1) * self.period_s
        self._next += expirations * self.period_s
        self._due(latest, expirations - 1)


def metronome(loop: asyncio.AbstractEventLoop,
              period_s: float) -> Metronome | TimerMetronome:
    """A :class:`TimerMetronome` where the kernel has timerfd (Linux), else the thread."""
    try:
        timer = _Timer.create()
    except OSError as exc:
        log.debug("no timerfd (%s): the control tick comes from a thread", exc)
        return Metronome(loop, period_s)
    return TimerMetronome(loop, period_s, timer)


# -- timerfd: os.timerfd_* from Python 3.13, libc through ctypes before ----------------------------

CLOCK_MONOTONIC = 1
TFD_TIMER_ABSTIME = 1


class _Timespec(ctypes.Structure):
    _fields_ = (("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long))


class _Itimerspec(ctypes.Structure):
    _fields_ = (("it_interval", _Timespec), ("it_value", _Timespec))


def _timespec(seconds: float) -> _Timespec:
    whole = int(seconds)
    return _Timespec(whole, round((seconds - whole) * 1e9))


class _Timer:
    """A non-blocking timerfd on CLOCK_MONOTONIC."""

    def __init__(self, fd: int, libc: ctypes.CDLL | None) -> None:
        self.fd = fd
        self._libc = libc

    @classmethod
    def create(cls) -> _Timer:
        if not sys.platform.startswith("linux"):
            raise OSError("timerfd is Linux only")
        flags = os.O_NONBLOCK | os.O_CLOEXEC  # TFD_NONBLOCK, TFD_CLOEXEC
        if hasattr(os, "timerfd_create"):  # Python 3.13
            return cls(os.timerfd_create(CLOCK_MONOTONIC, flags=flags), None)
        try:
            libc = ctypes.CDLL("libc.so.6", use_errno=True)
            create = libc.timerfd_create
        except (OSError, AttributeError) as exc:
            raise OSError(f"libc has no timerfd: {exc}") from None
        fd = create(CLOCK_MONOTONIC, flags)
        if fd < 0:
            errno = ctypes.get_errno()
            raise OSError(errno, os.strerror(errno))
        return cls(fd, libc)

    def arm(self, first: float, interval: float) -> None:
        """Expire at monotonic ``first``, then every ``interval`` seconds."""
        if self._libc is None:
            os.timerfd_settime(self.fd, flags=TFD_TIMER_ABSTIME,  # type: ignore[attr-defined]
                               initial=first, interval=interval)
            return
        spec = _Itimerspec(_timespec(interval), _timespec(first))
        if self._libc.timerfd_settime(self.fd, TFD_TIMER_ABSTIME, ctypes.byref(spec), None):
            errno = ctypes.get_errno()
            raise OSError(errno, os.strerror(errno))

    def read(self) -> int:
        """Expirations since the last read (0 when none: a spurious wake-up)."""
        try:
            return int.from_bytes(os.read(self.fd, 8), sys.byteorder)
        except BlockingIOError:
            return 0

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1
