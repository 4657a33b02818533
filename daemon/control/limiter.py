# Per-axis speed limiter: velocity clamp, acceleration, separate and emergency deceleration, jerk.
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class AxisLimits:
    max_velocity: float
    max_acceleration: float
    max_deceleration: float
    emergency_deceleration: float
    max_jerk: float = 0.0


class AxisLimiter:
    """Moves one axis's velocity toward a target within its limits, one step at a time.

    Slowing toward zero (or reversing) uses the deceleration limit, speeding up the
    acceleration limit; ``emergency=True`` slows with the emergency deceleration (speeding up
    still uses the acceleration limit). With a jerk limit
    the acceleration itself changes at most ``max_jerk`` per second.
    """

    def __init__(self, limits: AxisLimits) -> None:
        self.limits = limits
        self.velocity = 0.0
        self.acceleration = 0.0

    def clamp_target(self, target: float) -> tuple[float, bool]:
        """The target clamped to ±max_velocity, and whether it was clamped."""
        v = self.limits.max_velocity
        clamped = max(-v, min(v, target))
        return clamped, clamped != target

    def step(self, target: float, dt: float, emergency: bool = False) -> float:
        if dt <= 0:
            return self.velocity
        target, _ = self.clamp_target(target)
        rate = self._rate_limit(target, emergency)
        wanted = (target - self.velocity) / dt
        accel = max(-rate, min(rate, wanted))
        if self.limits.max_jerk > 0 and not emergency:
            jerk_step = self.limits.max_jerk * dt
            accel = max(self.acceleration - jerk_step, min(self.acceleration + jerk_step, accel))
        new = self.velocity + accel * dt
        if (target - self.velocity) * (target - new) < 0:  # would overshoot the target
            new = target
        self.acceleration = (new - self.velocity) / dt
        self.velocity = new
        return new

    def _rate_limit(self, target: float, emergency: bool) -> float:
        slowing = abs(target) < abs(self.velocity) or (math.copysign(1, target) != math.copysign(
            1, self.velocity) and self.velocity != 0.0)
        if not slowing:
            return self.limits.max_acceleration
        return self.limits.emergency_deceleration if emergency else self.limits.max_deceleration

    def reset(self) -> None:
        self.velocity = 0.0
        self.acceleration = 0.0
