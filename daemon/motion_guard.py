# What the control loop asks of a motion guard (the collision monitor) on every step.
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol


@dataclass(frozen=True)
class Guarded:
    """A target twist after the guard: the safe target, whether the limiter must brake
    with the emergency deceleration to honour it, and what the guard did (for reports)."""

    linear: float
    angular: float
    brake: bool = False
    action: str = "none"


class MotionGuard(Protocol):
    """Sits between the arbiter and the limiter for every command source.

    ``limit`` runs on every control step (event path and tick), so it must be cheap;
    ``observe`` gets the odometry pose once per tick.
    """

    def limit(self, linear: float, angular: float, current_linear: float,
              current_angular: float, now: float) -> Guarded: ...

    def observe(self, now: float, x: float, y: float, theta: float) -> None: ...
