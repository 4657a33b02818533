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
        if target == self.velocity and self.acceleration == 0.0:
            # holding a speed (a steady command, every command and tick): what the arithmetic
            # below gives, the velocity plus a zero step (-0.0 becomes 0.0 there too)
            self.velocity = new = self.velocity + 0.0
            return new
        return self.limited_step(target, dt, emergency)

    def limited_step(self, target: float, dt: float, emergency: bool = False) -> float:
        """:meth:`step` without its shortcut for a held speed (``dt`` > 0)."""
        limits = self.limits
        vmax = limits.max_velocity
        target = max(-vmax, min(vmax, target))
        velocity = self.velocity
        rate = self._rate_limit(target, velocity, emergency)
        wanted = (target - velocity) / dt
        accel = max(-rate, min(rate, wanted))
        if limits.max_jerk > 0 and not emergency:
            jerk_step = limits.max_jerk * dt
            accel = max(self.acceleration - jerk_step, min(self.acceleration + jerk_step, accel))
        new = velocity + accel * dt
        if (target - velocity) * (target - new) < 0:  # would overshoot the target
            new = target
        self.acceleration = (new - velocity) / dt
        self.velocity = new
        return new

    def _rate_limit(self, target: float, velocity: float, emergency: bool) -> float:
        """Slowing toward zero or reversing decelerates; anything else accelerates."""
        if abs(target) < abs(velocity) or (velocity != 0.0 and math.copysign(1, target)
                                           != math.copysign(1, velocity)):
            return self.limits.emergency_deceleration if emergency \
                else self.limits.max_deceleration
        return self.limits.max_acceleration

    def at_rest(self) -> bool:
        """Still and not accelerating: a step toward zero leaves it so (nothing to compute)."""
        return self.velocity == 0.0 and self.acceleration == 0.0

    def rest(self) -> None:
        """What a step toward zero does at rest (a ``-0.0`` left by a step becomes ``0.0``)."""
        self.velocity = self.acceleration = 0.0

    def reset(self) -> None:
        self.velocity = 0.0
        self.acceleration = 0.0
