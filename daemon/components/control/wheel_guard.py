# Measured wheel speeds from the encoders, and a guard that stops the robot when they disagree
# with the command for too long (a motor reversed against its encoder, a stall, a runaway).
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from drivers import EncoderReading

if TYPE_CHECKING:
    from daemon.settings import ControlSettings

SIDES = ("left", "right")


@dataclass(frozen=True)
class GuardSettings:
    """``[control] wheel_mismatch_*``: how far and how long a wheel may miss its command."""

    time_s: float = 0.5  # 0 disables the guard
    tolerance: float = 0.5  # fraction of the commanded speed
    min_rad_s: float = 1.5  # and always this much, rad/s
    lag_s: float = 0.3  # a wheel may still be at any command of this long ago
    window_s: float = 0.15  # speeds are measured over this long

    @classmethod
    def from_control(cls, control: ControlSettings) -> GuardSettings:
        return cls(control.wheel_mismatch_time_s, control.wheel_mismatch_tolerance,
                   control.wheel_mismatch_min_rad_s, control.wheel_mismatch_lag_s)


class WheelGuard:
    """Differentiates encoder readings into wheel speeds (rad/s, over ``window_s``) and trips
    once a wheel has stayed outside the commands of the last ``lag_s`` (widened by
    ``tolerance`` of the largest and ``min_rad_s``) for ``time_s``, so a ramp never trips it.
    A trip latches until :meth:`reset` (the e-stop release)."""

    def __init__(self, settings: GuardSettings) -> None:
        self.settings = settings
        self.measured: tuple[float, float] | None = None
        self.tripped: str | None = None
        self.trips = 0
        self._readings: deque[EncoderReading] = deque()
        self._since: list[float | None] = [None, None]
        self._quiet_until = -float("inf")
        #: times the guard started afresh after the wheels were stopped behind its back
        self.restarts = 0
        #: the wheel speeds written during the last lag_s: times, and each wheel's speeds
        self._times: deque[float] = deque()
        self._wheels: tuple[deque[float], deque[float]] = (deque(), deque())
        #: when a wheel was last written a speed other than zero (None: not since forgotten)
        self._moving_at: float | None = None

    def update(self, reading: EncoderReading | None, commanded: tuple[float, float],
               now: float) -> str | None:
        """Take this tick's reading and the wheel speeds last written; the reason when the
        guard trips now."""
        if reading is None:
            self.forget()
            return None
        self._measure(reading)
        self._remember(commanded, now)
        if self.measured is None or self.tripped or self.settings.time_s <= 0:
            return None
        if now < self._quiet_until:  # the wheels may still be coasting down from a stop
            self._since = [None, None]
            return None
        if self._still(self.measured, now):
            return None
        for index, side in enumerate(SIDES):
            reason = self._check(index, side, commanded[index], now)
            if reason:
                self.tripped = reason
                self.trips += 1
                return reason
        return None

    def _measure(self, reading: EncoderReading) -> None:
        readings = self._readings
        if readings and reading.t_mono <= readings[-1].t_mono:
            return  # the driver has not read the encoders again since
        readings.append(reading)
        while len(readings) > 2 and reading.t_mono - readings[1].t_mono >= self.settings.window_s:
            readings.popleft()
        first = readings[0]
        span = reading.t_mono - first.t_mono
        if span >= self.settings.window_s / 2:
            self.measured = ((reading.left_rad - first.left_rad) / span,
                             (reading.right_rad - first.right_rad) / span)

    def _still(self, measured: tuple[float, float], now: float) -> bool:
        """Every speed written during the last ``lag_s`` was zero and both wheels measure
        within ``min_rad_s`` of it: what :meth:`_check` would find, for less (an idle robot)."""
        moving_at, limit = self._moving_at, self.settings.min_rad_s
        if moving_at is not None and now - moving_at <= self.settings.lag_s:
            return False
        left, right = measured
        if -limit <= left <= limit and -limit <= right <= limit:
            self._since = [None, None]
            return True
        return False

    def _remember(self, commanded: tuple[float, float], now: float) -> None:
        """Keep the speeds written during the last ``lag_s``. A write equal to the one before
        replaces its time: a window holds the newest of a run of equal writes whenever it
        holds any, so the minimum and maximum :meth:`_check` takes are the same (an idle robot
        keeps one entry, not ``lag_s`` worth)."""
        times, (left, right) = self._times, self._wheels
        if commanded[0] != 0.0 or commanded[1] != 0.0:
            self._moving_at = now
        if times and left[-1] == commanded[0] and right[-1] == commanded[1]:
            times[-1] = now
        else:
            times.append(now)
            left.append(commanded[0])
            right.append(commanded[1])
        while now - times[0] > self.settings.lag_s:
            times.popleft()
            left.popleft()
            right.popleft()

    def _check(self, index: int, side: str, commanded: float, now: float) -> str | None:
        assert self.measured is not None
        measured = self.measured[index]
        recent = self._wheels[index]
        low, high = min(recent), max(recent)
        margin = self.settings.tolerance * max(abs(low), abs(high)) + self.settings.min_rad_s
        if low - margin <= measured <= high + margin:
            self._since[index] = None
            return None
        since = self._since[index] = self._since[index] or now
        if now - since < self.settings.time_s:
            return None
        return (f"{side} wheel measured {measured:+.2f} rad/s while commanded {commanded:+.2f} "
                f"rad/s for {now - since:.2f} s ({_likely(measured, commanded)}); check it with "
                f"`arbiterd test-motors`, then release the e-stop")

    def forget(self) -> None:
        """No reading (fault, reconnect): start measuring afresh."""
        self._readings.clear()
        self.measured = None
        self._since = [None, None]
        self._times.clear()
        for wheel in self._wheels:
            wheel.clear()
        self._moving_at = None

    def restart(self, now: float) -> None:
        """The wheels were zeroed behind the loop's back (the stall supervisor's stop): the
        readings and commands from before say nothing about the speeds now (a measurement
        spanning the stall would average the turns made before the stop over all of it), and
        a wheel may still be coasting down from its old speed. Measure afresh, and judge again
        ``lag_s`` from ``now`` (a stall stop is no miswiring)."""
        self.forget()
        self._quiet_until = now + self.settings.lag_s
        self.restarts += 1

    def reset(self) -> None:
        """The e-stop was released: a fresh start."""
        self.tripped = None
        self.forget()

    def status(self) -> dict[str, float] | None:
        if self.measured is None:
            return None
        return {"left": round(self.measured[0], 4), "right": round(self.measured[1], 4)}

    def health(self) -> dict[str, Any]:
        return {"enabled": self.settings.time_s > 0, "tripped": self.tripped,
                "trips": self.trips, "restarts_after_stall": self.restarts}


def _likely(measured: float, commanded: float) -> str:
    if measured * commanded < 0:
        return "turning against the command: a motor reversed against its encoder?"
    if abs(measured) < abs(commanded):
        return "too slow: stalled, blocked or unpowered?"
    return "too fast: a runaway speed loop or a wrong counts_per_rev?"
