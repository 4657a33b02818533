# Shared wheel motor model for every emulator: first-order response, saturation, encoder counts.
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass


@dataclass
class WheelMotor:
    """One wheel driven by a DC motor, seen from outside as a first-order velocity response.

    ``target_rad_s`` is what the controller asks for (a duty cycle maps to
    ``duty * max_speed_rad_s``); ``speed_rad_s`` follows it with time constant
    ``time_constant_s`` and saturates at ``max_speed_rad_s``. ``position_rad`` integrates the
    speed; ``counts`` is what a quadrature encoder with ``counts_per_rev`` would read.
    ``direction`` is -1 for a wheel mounted mirrored (its encoder counts down going forward).
    """

    max_speed_rad_s: float = 40.0
    time_constant_s: float = 0.05
    counts_per_rev: int = 1440
    direction: int = 1
    target_rad_s: float = 0.0
    speed_rad_s: float = 0.0
    position_rad: float = 0.0

    def set_target(self, rad_s: float) -> None:
        self.target_rad_s = max(-self.max_speed_rad_s, min(self.max_speed_rad_s, rad_s))

    def set_duty(self, duty: float) -> None:
        """Drive with a duty cycle in -1..1 (open loop)."""
        self.set_target(max(-1.0, min(1.0, duty)) * self.max_speed_rad_s)

    def advance(self, dt: float) -> None:
        """Step the motor ``dt`` seconds (exact solution of the first-order lag)."""
        if dt <= 0:
            return
        start = self.speed_rad_s
        alpha = 1.0 - math.exp(-dt / self.time_constant_s) if self.time_constant_s > 0 else 1.0
        self.speed_rad_s = start + (self.target_rad_s - start) * alpha
        # integral of the exponential approach over dt
        if self.time_constant_s > 0:
            lag = (start - self.target_rad_s) * self.time_constant_s * alpha
            moved = self.target_rad_s * dt + lag
        else:
            moved = self.target_rad_s * dt
        self.position_rad += moved

    @property
    def counts(self) -> int:
        turns = self.position_rad / (2 * math.pi)
        return self.direction * math.floor(turns * self.counts_per_rev)


class MotorPair:
    """Left and right wheel motors advanced together, either by the world or by real time.

    Emulators read and command the motors through this object. With ``clock`` set (the
    default is ``time.monotonic``), every access first advances the motors to the clock's
    current time, so a standalone emulator needs no thread. The simulated world passes
    ``clock=None`` and calls :meth:`advance` from its own physics step instead.
    """

    def __init__(self, left: WheelMotor | None = None, right: WheelMotor | None = None,
                 clock: Callable[[], float] | None = time.monotonic) -> None:
        self.left = left or WheelMotor()
        self.right = right or WheelMotor()
        self.lock = threading.RLock()
        self._clock = clock
        self._last = clock() if clock else 0.0

    def sync(self) -> None:
        """Advance to the clock's current time (no-op when the world drives the motors)."""
        if self._clock is None:
            return
        with self.lock:
            now = self._clock()
            self.advance(now - self._last)
            self._last = now

    def advance(self, dt: float) -> None:
        with self.lock:
            self.left.advance(dt)
            self.right.advance(dt)

    def set_targets(self, left_rad_s: float, right_rad_s: float) -> None:
        with self.lock:
            self.sync()
            self.left.set_target(left_rad_s)
            self.right.set_target(right_rad_s)

    def set_duties(self, left: float, right: float) -> None:
        with self.lock:
            self.sync()
            self.left.set_duty(left)
            self.right.set_duty(right)

    def speeds(self) -> tuple[float, float]:
        with self.lock:
            self.sync()
            return self.left.speed_rad_s, self.right.speed_rad_s

    def targets(self) -> tuple[float, float]:
        with self.lock:
            return self.left.target_rad_s, self.right.target_rad_s

    def positions(self) -> tuple[float, float]:
        with self.lock:
            self.sync()
            return self.left.position_rad, self.right.position_rad

    def counts(self) -> tuple[int, int]:
        with self.lock:
            self.sync()
            return self.left.counts, self.right.counts


def now() -> float:
    return time.monotonic()
