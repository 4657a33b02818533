# The navigation state machine: plan, follow, recover, succeed or fail with a reason; clockless.
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from nav.planner import Plan
from nav.pursuit import Command, Pose, Pursuit, PursuitSettings, densify

#: states a goal goes through; the last three end it
STATES = ("idle", "planning", "following", "recovering", "succeeded", "failed", "canceled")
ACTIVE = ("planning", "following", "recovering")
#: the recoveries in turn when the robot is stuck: (name, seconds, linear m/s, angular rad/s)
RECOVERIES = (("wait", 1.0, 0.0, 0.0), ("back up", 2.0, -0.1, 0.0),
              ("rotate", 2.0, 0.0, 1.0))
#: the remaining distance must shrink by this much to count as progress (m)
PROGRESS_M = 0.2
#: a scan stale this long fails the goal (s)
STALE_FAIL_S = 5.0
#: the points of a path the follower gets are at most this far apart (m)
PATH_SPACING_M = 0.05


@dataclass(frozen=True)
class NavigatorSettings:
    pursuit: PursuitSettings
    replan_period_s: float = 1.0
    progress_timeout_s: float = 20.0
    held_timeout_s: float = 2.0
    goal_timeout_s: float = 30.0


@dataclass
class Target:
    """What the robot is asked to do: reach a pose (``path`` None, planned) or follow a path
    (given); coordinates in ``frame``."""

    frame: str
    x: float
    y: float
    yaw: float | None
    path: np.ndarray | None = None
    name: str = ""
    number: int = 0
    #: tighter (or looser) than the settings' for this goal (m, rad), e.g. the fetch's
    xy_tolerance: float | None = None
    yaw_tolerance: float | None = None


@dataclass
class Tracking:
    """Cross-track error of a followed path."""

    squares: float = 0.0
    count: int = 0
    worst: float = 0.0

    def add(self, error: float) -> None:
        self.squares += error * error
        self.count += 1
        self.worst = max(self.worst, error)

    @property
    def rms(self) -> float:
        return math.sqrt(self.squares / self.count) if self.count else 0.0


@dataclass
class Progress:
    started: float = 0.0
    deadline: float = math.inf
    best: float = math.inf
    at: float = 0.0
    held_since: float | None = None
    stale_since: float | None = None
    recoveries: int = 0
    #: the best remaining distance when the last recovery started
    best_before_recovery: float = math.inf
    replans: int = 0
    recovery: str = ""
    recovery_until: float = 0.0
    tracking: Tracking = field(default_factory=Tracking)


class Navigator:
    """One goal at a time. The caller hands it the time, the pose in the goal's frame and
    what stops the robot; it answers with a twist and says when it wants a plan."""

    def __init__(self, settings: NavigatorSettings) -> None:
        self.settings = settings
        self.state = "idle"
        self.reason = ""
        self.target: Target | None = None
        self.pursuit: Pursuit | None = None
        self.progress = Progress()
        self.last = Command(0.0, 0.0, "", 0.0, 0.0)
        self.next_plan = math.inf
        self.goals = 0
        self.plan_points = np.zeros((0, 2))

    @property
    def active(self) -> bool:
        return self.state in ACTIVE

    # -- goals ---------------------------------------------------------------------------------

    def start(self, target: Target, now: float) -> None:
        """Go for ``target`` (a pose to plan to, or a path to follow); replaces any goal."""
        self.goals += 1
        target.number = self.goals
        self.target, self.pursuit = target, None
        self.progress = Progress(started=now, at=now,
                                 deadline=now + self.settings.goal_timeout_s)
        self.last = Command(0.0, 0.0, "", 0.0, 0.0)
        if target.path is None:
            self._set("planning", "", now)
            self.next_plan = now
        else:
            self._follow(target.path, target.yaw, now)
            self._set_deadline()

    def _set_deadline(self) -> None:
        """The goal's time budget: goal_timeout_s plus 2.5 x the path at top speed."""
        assert self.pursuit is not None
        s = self.settings
        self.progress.deadline = self.progress.started + s.goal_timeout_s + \
            2.5 * self.pursuit.length / s.pursuit.max_speed

    def _follow(self, points: np.ndarray, yaw: float | None, now: float) -> None:
        self.plan_points = np.asarray(points, dtype=float)
        settings, target = self.settings.pursuit, self.target
        if target is not None and target.xy_tolerance is not None:
            settings = replace(settings, xy_tolerance=target.xy_tolerance)
        if target is not None and target.yaw_tolerance is not None:
            settings = replace(settings, yaw_tolerance=target.yaw_tolerance)
        self.pursuit = Pursuit(settings, densify(points, PATH_SPACING_M), yaw)
        self._set("following", "", now)

    def end(self, state: str, reason: str, now: float) -> None:
        """Stop going for the goal: ``succeeded``, ``failed`` or ``canceled``."""
        if self.active:
            self._set(state, reason, now)
        self.next_plan = math.inf

    def _set(self, state: str, reason: str, now: float) -> None:
        self.state, self.reason = state, reason

    # -- plans ---------------------------------------------------------------------------------

    def wants_plan(self, now: float) -> bool:
        target = self.target
        if target is None or target.path is not None or not self.active:
            return False
        if self.pursuit is not None and self.pursuit.arrived:
            return False
        return now >= self.next_plan and self.state != "recovering"

    def planning(self, now: float) -> None:
        """A plan was asked for; the next one not before a replan period."""
        self.next_plan = now + self.settings.replan_period_s

    def planned(self, plan: Plan, now: float, number: int, yaw: float | None) -> bool:
        """A plan for goal ``number`` came back; ``yaw``: the goal's heading in the plan's
        frame (None: any). Whether it is followed now."""
        target = self.target
        if target is None or number != target.number or not self.active \
                or self.state == "recovering":
            return False
        self.progress.replans += 1
        if not plan.found:
            if plan.final:
                self.end("failed", plan.reason, now)
            else:
                self.stuck(plan.reason, now)
            return False
        first = self.pursuit is None
        self._follow(plan.points, yaw, now)
        assert self.pursuit is not None
        if first:
            self._set_deadline()
        self.next_plan = now + self.settings.replan_period_s
        return True

    # -- stuck ---------------------------------------------------------------------------------

    def stuck(self, reason: str, now: float) -> None:
        """Start the next recovery, or fail with ``reason`` when none is left."""
        progress = self.progress
        if progress.recoveries >= len(RECOVERIES):
            self.end("failed", f"{reason} (after {len(RECOVERIES)} recoveries: "
                     f"{', '.join(r[0] for r in RECOVERIES)})", now)
            return
        name, seconds, _, _ = RECOVERIES[progress.recoveries]
        progress.recoveries += 1
        progress.best_before_recovery = min(progress.best, progress.best_before_recovery)
        progress.recovery, progress.recovery_until = name, now + seconds
        progress.held_since = None
        self._set("recovering", f"{name}: {reason}", now)

    def _recover(self, now: float) -> tuple[float, float]:
        progress = self.progress
        if now < progress.recovery_until:
            for name, _, v, w in RECOVERIES:
                if name == progress.recovery:
                    return v, w
        self._set("planning", "", now)
        progress.best, progress.at = math.inf, now  # a fresh start after the recovery
        self.next_plan = now
        return 0.0, 0.0

    # -- the decision --------------------------------------------------------------------------

    def decide(self, now: float, pose: Pose, speed: float, stopped: str | None,
               held: bool) -> tuple[float, float]:
        """The twist for now. ``stopped``: why the robot may not move (a stale scan), None
        when it may; ``held``: the collision monitor stops it."""
        if not self.active:
            return 0.0, 0.0
        progress = self.progress
        if now > progress.deadline:
            self.end("failed", f"timed out after {now - progress.started:.0f} s: the goal "
                     "looks unreachable (walled off, or no way found)", now)
            return 0.0, 0.0
        if stopped is not None:
            progress.stale_since = progress.stale_since if progress.stale_since is not None \
                else now
            if now - progress.stale_since > STALE_FAIL_S:
                self.end("failed", f"{stopped} for {STALE_FAIL_S:g} s", now)
            return 0.0, 0.0
        progress.stale_since = None
        if self.state == "recovering":
            return self._recover(now)
        if self.state == "planning" or self.pursuit is None:
            return 0.0, 0.0
        return self._follow_step(now, pose, speed, held)

    def _follow_step(self, now: float, pose: Pose, speed: float,
                     held: bool) -> tuple[float, float]:
        assert self.pursuit is not None
        command = self.last = self.pursuit.step(pose, speed)
        progress = self.progress
        if command.phase == "arrived":
            self.end("succeeded", "", now)
            return 0.0, 0.0
        if command.phase == "follow":
            progress.tracking.add(command.cross_track_m)
        if command.remaining_m < progress.best_before_recovery - 5 * PROGRESS_M:
            progress.recoveries, progress.best_before_recovery = 0, math.inf
        if command.remaining_m < progress.best - PROGRESS_M:
            progress.best, progress.at = command.remaining_m, now
        elif now - progress.at > self.settings.progress_timeout_s:
            self.stuck(f"no progress for {self.settings.progress_timeout_s:g} s", now)
            return 0.0, 0.0
        if held and command.phase != "align":
            progress.held_since = progress.held_since if progress.held_since is not None \
                else now
            if now - progress.held_since > self.settings.held_timeout_s:
                self.stuck("the collision monitor holds the robot: something is in the way",
                           now)
                return 0.0, 0.0
        else:
            progress.held_since = None
        return command.v, command.w

    def eta_s(self) -> float | None:
        if not self.active or self.pursuit is None:
            return None
        return round(self.last.remaining_m / self.settings.pursuit.max_speed, 1)
