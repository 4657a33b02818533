# Fixed-rate tick source: a kernel timer the event loop watches, or a thread sleeping to deadlines.
from __future__ import annotations

import asyncio
import ctypes
import logging
import math
import os
import sys
import threading
import time

log = logging.getLogger("arbiterd.control")


class Metronome:
    """Delivers ticks at ``next += period`` deadlines to a coroutine waiting in :meth:`wait`.

    Sleeping in a thread with ``time.sleep`` is accurate to tens of microseconds, where the
    event loop's own timers round up to whole milliseconds. If the loop has not consumed the
    previous tick (it is blocked), the deadline is counted as missed instead of queued, so a
    stalled loop never receives a burst of stale ticks.

    This is the portable fallback of :class:`TimerMetronome` (see :func:`metronome`): it costs
    a thread that wakes every period and then wakes the event loop through its self-pipe.
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


class TimerMetronome:
    """The same ticks from a kernel timer (Linux ``timerfd`` on ``CLOCK_MONOTONIC``, the clock
    of ``time.monotonic``) that the event loop watches like a socket: the kernel wakes the loop
    at each absolute deadline (``next += period`` is the timer's own interval, so nothing
    drifts), to the tens of microseconds of a sleeping thread, without the thread. One wake-up
    per tick instead of two plus a self-pipe write and read: the idle daemon's largest cost.

    Expirations the loop could not take while it was blocked are counted as missed, never
    delivered late in a burst: after a stall the loop gets one tick, the latest deadline.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, period_s: float, timer: _Timer) -> None:
        self.loop = loop
        self.period_s = period_s
        self.missed = 0
        self._timer = timer
        self._next = 0.0  # the timer's next expiration
        self._deadline = 0.0
        self._pending = False
        self._waiter: asyncio.Future[None] | None = None  # what :meth:`wait` awaits

    def start(self) -> None:
        self._next = time.monotonic() + self.period_s
        self._timer.arm(self._next, self.period_s)
        self.loop.add_reader(self._timer.fd, self._on_timer)

    def stop(self) -> None:
        if self._timer.fd >= 0:
            self.loop.remove_reader(self._timer.fd)
            self._timer.close()

    async def wait(self) -> float:
        """Wait for the next tick; returns its deadline (monotonic seconds)."""
        if not self._pending:  # a bare future: an asyncio.Event costs two more layers a tick
            self._waiter = waiter = self.loop.create_future()
            try:
                await waiter
            finally:
                self._waiter = None
        self._pending = False
        return self._deadline

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
        if self._pending:  # the last tick is not consumed yet: all of these are missed
            self.missed += expirations
            return
        self.missed += expirations - 1
        self._pending = True
        self._deadline = latest
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)


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
