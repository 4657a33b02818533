# The wander behaviour: a six-state FSM over the free-space histogram (IDLE ... STOPPED).
from __future__ import annotations

import math
import random
from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]

STATES = ("IDLE", "CRUISE", "AVOID", "ROTATE", "BACKUP", "STOPPED")


@dataclass(frozen=True)
class WanderSettings:
    """Speeds and distances of the wander behaviour (``[autonomy]``)."""

    cruise_speed: float = 0.6
    turn_speed: float = 1.5
    look_ahead: float = 1.6  # free distance ahead below which it starts avoiding, m
    rotate_distance: float = 0.45  # free distance ahead below which it turns in place, m
    backup_speed: float = 0.15
    backup_s: float = 1.2
    steer_gain: float = 2.0
    goal_period_s: tuple[float, float] = (6.0, 15.0)  # a new wander heading this often
    rotate_limit_rad: float = 1.75 * math.pi  # turned this far without finding a way: back up
    traps: int = 3  # this many ROTATE entries within trap_window_s: back up first
    trap_window_s: float = 8.0


@dataclass(frozen=True)
class Perception:
    """What the behaviour sees at one decision.

    ``free`` (per sector, counter-clockwise from straight ahead, angles in ``angles``) is the
    straight-line free travel with the clearance the behaviour likes to keep, ``tight`` the
    same with only what the robot needs at the least (None: same as ``free``); ``heading``
    the odometry heading; ``blocked`` why the robot may not move (e-stop, fault, stale scan),
    else None; ``held`` True when the collision monitor is stopping the robot.
    """

    free: Array
    angles: Array
    heading: float
    blocked: str | None = None
    held: bool = False
    tight: Array | None = None

    @property
    def room(self) -> Array:
        """The tight histogram (where the robot can go at all)."""
        return self.free if self.tight is None else self.tight


class Wander:
    """IDLE → CRUISE ⇄ AVOID → ROTATE ⇄ BACKUP, STOPPED from any state (see docs/autonomy.md).

    :meth:`decide` takes the time and a :class:`Perception` and returns the twist to command.
    Randomness (the wander heading) comes from ``rng`` so a seeded run repeats exactly.
    """

    def __init__(self, settings: WanderSettings, rng: random.Random) -> None:
        self.settings = settings
        self.rng = rng
        self.state = "IDLE"
        self.since = 0.0
        self.transitions = 0
        self.time_in: dict[str, float] = dict.fromkeys(STATES, 0.0)
        self.reason = ""
        self._last = 0.0
        self._goal = 0.0  # wander heading, odometry frame
        self._next_goal = 0.0
        self._side = 1.0  # committed turn side in AVOID/ROTATE
        self._rotate_target = 0.0
        self._rotated = 0.0
        self._last_heading = 0.0
        self._rotations: deque[float] = deque(maxlen=8)
        self._backup_until = 0.0

    # -- bookkeeping ---------------------------------------------------------------------------

    def start(self, now: float, heading: float) -> None:
        self._last = now
        self._goal = heading
        self._next_goal = now
        self._go("CRUISE", now, "wander started")

    def stop(self, now: float, reason: str = "off") -> None:
        self._account(now)
        self._go("IDLE", now, reason)

    def _go(self, state: str, now: float, reason: str) -> None:
        if state != self.state:
            self.transitions += 1
            self.state, self.since = state, now
        self.reason = reason

    def times(self, now: float) -> dict[str, float]:
        """Seconds spent in each state, up to ``now``."""
        times = dict(self.time_in)
        if self.state != "IDLE":
            times[self.state] += max(0.0, now - self._last)
        return times

    def _account(self, now: float) -> None:
        self.time_in[self.state] += max(0.0, now - self._last)
        self._last = now

    # -- deciding ------------------------------------------------------------------------------

    def decide(self, now: float, seen: Perception) -> tuple[float, float]:
        self._account(now)
        if self.state == "IDLE":
            return 0.0, 0.0
        if seen.blocked:
            self._go("STOPPED", now, seen.blocked)
            return 0.0, 0.0
        if self.state == "STOPPED":
            self._go("CRUISE", now, "clear to move again")
        self._update_goal(now, seen.heading)
        handler = {"CRUISE": self._cruise, "AVOID": self._avoid, "ROTATE": self._rotate,
                   "BACKUP": self._backup}[self.state]
        return handler(now, seen)

    def _update_goal(self, now: float, heading: float) -> None:
        if now >= self._next_goal:
            self._goal = self.rng.uniform(-math.pi, math.pi)
            self._next_goal = now + self.rng.uniform(*self.settings.goal_period_s)
        self._rotated += abs(_wrap(heading - self._last_heading))
        self._last_heading = heading

    def _cruise(self, now: float, seen: Perception) -> tuple[float, float]:
        s = self.settings
        ahead = _ahead(seen)
        if seen.held or float(seen.room[0]) < s.rotate_distance:
            return self._enter_rotate(now, seen, "blocked ahead")
        if ahead < s.look_ahead:
            self._side = math.copysign(1.0, self._best(seen, 150.0, goal_weight=0.3))
            self._go("AVOID", now, f"obstacle {ahead:.2f} m ahead")
            return self._avoid(now, seen)
        direction = self._best(seen, 90.0, goal_weight=0.5)
        return self._drive(direction, ahead, seen)

    def _avoid(self, now: float, seen: Perception) -> tuple[float, float]:
        s = self.settings
        ahead = _ahead(seen)
        if seen.held or float(seen.room[0]) < s.rotate_distance:
            return self._enter_rotate(now, seen, f"obstacle {float(seen.room[0]):.2f} m ahead")
        if ahead >= s.look_ahead * 1.25:
            self._go("CRUISE", now, "way ahead is clear")
            return self._cruise(now, seen)
        direction = self._best(seen, 150.0, goal_weight=0.1, side=self._side)
        return self._drive(direction, ahead, seen)

    def _drive(self, direction: float, ahead: float, seen: Perception) -> tuple[float, float]:
        """Forward along an arc toward ``direction``, slower when the way is short or the
        turn is sharp."""
        s = self.settings
        room = (ahead - s.rotate_distance) / max(s.look_ahead - s.rotate_distance, 1e-6)
        speed = s.cruise_speed * min(1.0, max(0.25, room))
        speed *= max(0.2, math.cos(min(abs(direction), math.pi / 2)))
        turn = max(-s.turn_speed, min(s.turn_speed, s.steer_gain * direction))
        return speed, turn

    def _enter_rotate(self, now: float, seen: Perception, reason: str) -> tuple[float, float]:
        self._rotations.append(now)
        recent = [t for t in self._rotations if now - t <= self.settings.trap_window_s]
        if len(recent) >= self.settings.traps and self.state != "BACKUP":
            self._rotations.clear()
            return self._enter_backup(now, seen, "turning back and forth: backing out")
        target = self._freest(seen)
        self._side = math.copysign(1.0, target) if abs(target) > 1e-6 else self._side
        self._rotate_target = seen.heading + target
        self._rotated = 0.0
        self._go("ROTATE", now, reason)
        return self._rotate(now, seen)

    def _rotate(self, now: float, seen: Perception) -> tuple[float, float]:
        s = self.settings
        error = _wrap(self._rotate_target - seen.heading)
        if abs(error) < math.radians(12.0) and float(seen.room[0]) >= s.rotate_distance * 1.5:
            self._go("CRUISE", now, "facing free space")
            return 0.0, 0.0
        if self._rotated > s.rotate_limit_rad:
            return self._enter_backup(now, seen, "no way out found turning")
        if np.max(seen.room) < s.rotate_distance * 1.5:
            return self._enter_backup(now, seen, "boxed in")
        rate = min(s.turn_speed, 2.5 * abs(error) + 0.3)
        return 0.0, self._side * rate

    def _enter_backup(self, now: float, seen: Perception, reason: str) -> tuple[float, float]:
        self._backup_until = now + self.settings.backup_s
        self._side = -self._side
        self._go("BACKUP", now, reason)
        return self._backup(now, seen)

    def _backup(self, now: float, seen: Perception) -> tuple[float, float]:
        behind = float(seen.room[len(seen.room) // 2])
        if now >= self._backup_until or behind < 0.05:
            target = self._freest(seen)
            self._rotate_target = seen.heading + target
            self._rotated = 0.0
            self._go("ROTATE", now, "backed out")
            return 0.0, 0.0
        return -self.settings.backup_speed, 0.0

    # -- choosing directions -------------------------------------------------------------------

    def _best(self, seen: Perception, within_deg: float, goal_weight: float,
              side: float = 0.0) -> float:
        """The direction (robot frame) with the best mix of free room, closeness to the wander
        heading and little turning; optionally only on one ``side``."""
        look = self.settings.look_ahead
        angles = seen.angles
        goal = _wrap(self._goal - seen.heading)
        score = np.minimum(seen.free, 2.0 * look) / (2.0 * look)
        score -= goal_weight * np.abs(_wrap_array(angles - goal)) / math.pi
        score -= 0.3 * np.abs(angles) / math.pi
        allowed = np.abs(angles) <= math.radians(within_deg)
        if side:
            allowed &= (angles * side >= 0)
        for room in (seen.free, seen.room):  # comfortable first, else wherever it fits
            fits = allowed & (room >= self.settings.rotate_distance)
            if fits.any():
                return float(angles[np.argmax(np.where(fits, score, -np.inf))])
        return 0.0

    def _freest(self, seen: Perception) -> float:
        """Where to turn in place: the most open direction (comfortably if there is such
        room, else where the robot fits), nearer ones and the committed side preferred."""
        angles = seen.angles
        room = seen.free if np.max(seen.free) >= 1.5 * self.settings.rotate_distance else \
            seen.room
        score = room - 0.15 * np.abs(angles) - 0.05 * (angles * self._side < 0)
        best = float(angles[int(np.argmax(score))])
        return best if abs(best) > 1e-6 else math.pi * self._side


def _ahead(seen: Perception) -> float:
    return float(seen.free[0])


def _wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


def _wrap_array(angles: Array) -> Array:
    return np.asarray(np.arctan2(np.sin(angles), np.cos(angles)))
