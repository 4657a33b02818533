# Frontier exploration's state machine: pick a frontier, go, blacklist failures, come back;
# clockless (handed the time and the frontiers, it answers with where to go).
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from nav.frontier import Frontier, choose
from slam.pose import Pose2

#: states of an exploration; the last three end it
STATES = ("idle", "exploring", "returning", "done", "failed", "canceled")
RUNNING = ("exploring", "returning")


@dataclass(frozen=True)
class ExploreSettings:
    """``look_period_s``: how often the frontiers are looked at again while driving to one;
    ``size_weight``: how many metres of way a metre of frontier is worth;
    ``min_frontier_cells``: smaller clusters are ignored; ``blacklist_radius_m``: a frontier
    with a cell this near a failed (or reached but still unseen) goal is not chosen again;
    ``keep_radius_m``: the goal is kept while a frontier cell lies this near it."""

    look_period_s: float = 1.0
    size_weight: float = 0.5
    min_frontier_cells: int = 3
    blacklist_radius_m: float = 0.5
    keep_radius_m: float = 0.3


@dataclass(frozen=True)
class Go:
    """Where the explorer wants to go next (the start pose when ``home``)."""

    x: float
    y: float
    yaw: float | None = None
    home: bool = False


@dataclass
class Exploration:
    """What one exploration did so far."""

    started: float = 0.0
    ended: float | None = None
    goals: int = 0
    failed_goals: int = 0
    explored_m2: float = 0.0
    frontiers: int = 0
    blacklist: list[tuple[float, float]] = field(default_factory=list)


class Explorer:
    """One exploration at a time: while ``exploring`` it looks at the frontiers (when a goal
    ended, and every ``look_period_s`` while one runs) and goes for the best one, keeping its
    goal while that frontier is still there; a goal that fails blacklists its frontier (so
    does one reached whose frontier stays). When no frontier is left it goes back to the start
    pose (``returning``) and ends ``done``; a problem of the robot (e-stop, fault, stale
    scans) ends it ``failed``, someone else's goal or command ``canceled``."""

    def __init__(self, settings: ExploreSettings | None = None) -> None:
        self.settings = settings or ExploreSettings()
        self.state = "idle"
        self.reason = ""
        self.home: Pose2 = (0.0, 0.0, 0.0)
        self.target: Frontier | None = None
        #: the navigator's number of the goal the explorer sent last
        self.goal_number = 0
        self.run = Exploration()
        self.next_look = math.inf

    @property
    def running(self) -> bool:
        return self.state in RUNNING

    def start(self, now: float, home: Pose2) -> None:
        self.state, self.reason, self.home = "exploring", "", home
        self.target, self.goal_number = None, 0
        self.run = Exploration(started=now)
        self.next_look = now

    def end(self, state: str, reason: str, now: float) -> None:
        if not self.running:
            return
        self.state, self.reason = state, reason
        self.run.ended = now
        self.next_look = math.inf

    def wants_look(self, now: float) -> bool:
        return self.state == "exploring" and now >= self.next_look

    def looked(self, now: float, frontiers: list[Frontier], explored_m2: float,
               following: bool) -> Go | None:
        """The frontiers found now (``following``: the explorer's goal is still running):
        where to go next, or None to carry on."""
        s, run = self.settings, self.run
        run.explored_m2 = explored_m2
        self.next_look = now + s.look_period_s
        if self.state != "exploring":
            return None
        allowed = [f for f in frontiers
                   if not any(f.near(x, y, s.blacklist_radius_m) for x, y in run.blacklist)]
        run.frontiers = len(allowed)
        target = self.target
        if following and target is not None and \
                any(f.near(target.x, target.y, s.keep_radius_m) for f in allowed):
            return None
        if explored_m2 <= 0.0:
            return None  # nothing seen yet: the first revolutions are still to come
        best = choose(allowed, s.size_weight)
        if best is None:
            self.state, self.target = "returning", None
            x, y, yaw = self.home
            return Go(x, y, yaw, home=True)
        self.target = best
        return Go(best.x, best.y)

    def sent(self, goal_number: int) -> None:
        """The goal of the last :meth:`looked` was started as the navigator's ``goal_number``."""
        self.goal_number = goal_number
        self.run.goals += 1

    def refused(self, go: Go, reason: str, now: float) -> None:
        """The goal of the last :meth:`looked` was refused at once."""
        if go.home:
            self.end("failed", f"could not return to the start: {reason}", now)
            return
        self._blacklist()
        self.next_look = now

    def goal_ended(self, number: int, state: str, reason: str, problem: str | None,
                   now: float) -> None:
        """The navigator's goal ``number`` ended ``state`` (``problem``: the robot cannot go
        on: e-stop, fault, stale scans)."""
        if not self.running or number != self.goal_number:
            return
        self.goal_number = 0  # handled (the navigator may report one end twice)
        if problem:
            self.end("failed", problem, now)
        elif state == "canceled":
            self.end("canceled", reason, now)
        elif self.state == "returning":
            if state == "succeeded":
                self.end("done", "", now)
            else:
                self.end("failed", f"could not return to the start: {reason}", now)
        else:
            if state == "failed":
                self.run.failed_goals += 1
            # failed: not reachable; succeeded: there, so a frontier left here cannot be seen
            self._blacklist()
            self.next_look = now

    def _blacklist(self) -> None:
        if self.target is not None:
            self.run.blacklist.append((self.target.x, self.target.y))
        self.target = None

    def status(self, now: float) -> dict[str, Any]:
        run = self.run
        end = run.ended if run.ended is not None else now
        target = self.target
        return {"state": self.state, "reason": self.reason,
                "explored_m2": round(run.explored_m2, 2),
                "elapsed_s": round(max(0.0, end - run.started), 2) if self.state != "idle"
                else 0.0,
                "goals": run.goals, "failed_goals": run.failed_goals,
                "frontiers": run.frontiers, "blacklisted": len(run.blacklist),
                "target": None if target is None else [round(target.x, 2), round(target.y, 2)],
                "home": [round(v, 3) for v in self.home]}
