# Joint-space moves: every joint arrives together, at the slowest joint's speed limit. Clockless.
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class Move:
    """A straight line in joint space from ``start`` to ``goal``, begun at ``t0`` and lasting
    ``duration`` s (every joint arrives at the same time)."""

    start: dict[str, float]
    goal: dict[str, float]
    t0: float
    duration: float

    def at(self, now: float) -> dict[str, float]:
        if self.duration <= 0.0 or now >= self.t0 + self.duration:
            return dict(self.goal)
        fraction = max(0.0, (now - self.t0) / self.duration)
        return {j: s + (self.goal[j] - s) * fraction for j, s in self.start.items()}

    def velocity(self, now: float) -> dict[str, float]:
        if self.duration <= 0.0 or not self.t0 <= now < self.t0 + self.duration:
            return dict.fromkeys(self.start, 0.0)
        return {j: (self.goal[j] - s) / self.duration for j, s in self.start.items()}


class JointMotion:
    """Where each joint should be at a time. :meth:`move_to` starts a new move from wherever
    the joints are at that instant (a move in progress is replaced without a jump); the
    duration is the longest ``|distance| / max_speed`` over the joints, so the slowest joint
    runs at its limit and the others slower, all arriving together. Given times, never reads
    a clock."""

    def __init__(self, max_speed: Mapping[str, float], positions: Mapping[str, float],
                 now: float) -> None:
        self.max_speed = dict(max_speed)
        self.move = Move(dict(positions), dict(positions), now, 0.0)

    def position(self, now: float) -> dict[str, float]:
        return self.move.at(now)

    def velocity(self, now: float) -> dict[str, float]:
        return self.move.velocity(now)

    @property
    def goal(self) -> dict[str, float]:
        return dict(self.move.goal)

    def arrival(self) -> float:
        return self.move.t0 + self.move.duration

    def moving(self, now: float) -> bool:
        return now < self.arrival() and self.move.goal != self.move.start

    def move_to(self, goals: Mapping[str, float], now: float) -> float:
        """Head for ``goals`` (a subset of the joints; the rest keep their goal); returns the
        move's duration, s."""
        start = self.position(now)
        goal = {**self.move.goal, **goals}
        duration = max(abs(goal[j] - start[j]) / self.max_speed[j] for j in start)
        self.move = Move(start, goal, now, duration)
        return duration

    def freeze(self, now: float) -> dict[str, float]:
        """Stop where the joints are now (the goal becomes the current position)."""
        here = self.position(now)
        self.move = Move(here, dict(here), now, 0.0)
        return here
