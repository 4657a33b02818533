# The fetch sequence: navigate, grasp, carry, deliver; every failure ends safe. Clockless.
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

#: the states, in the order a fetch goes through them
IDLE, NAV_TO_OBJECT, GRASP, NAV_TO_DROP, DELIVER = (
    "IDLE", "NAV_TO_OBJECT", "GRASP", "NAV_TO_DROP", "DELIVER")
#: standoff headings tried around a point (every 22.5°)
HEADINGS = 16
#: the last goal, facing the object (or the drop point), is reached within these (m, rad):
#: a heading error of e rad puts the tool point e x 0.565 m to the side at the grasp
FACE_XY_M, FACE_YAW_RAD = 0.02, 0.015

Pose2 = tuple[float, float, float]


class FetchError(ValueError):
    """A fetch that cannot start, with the reason for the client."""


class ArmError(Exception):
    """The arm did not take a move (the e-stop, a fault, a target outside its limits)."""


class Navigation(Protocol):
    """What the fetch asks of navigation (the navigation component, adapted)."""

    def go(self, x: float, y: float, yaw: float, tolerances: tuple[float, float] | None = None,
           ) -> None:
        """Start a goal (replacing any), reached within ``tolerances`` (m, rad; None: the
        navigation's own); ValueError says why it cannot start."""

    def outcome(self) -> tuple[str, str] | None:
        """None while the goal runs, else its end state and reason."""

    def cancel(self, reason: str) -> None: ...

    def pose(self) -> Pose2: ...

    def free(self, x: float, y: float) -> bool:
        """The robot may stand at (x, y) as far as the costmap knows."""


class Arm(Protocol):
    """What the fetch asks of the arm (its controller, adapted)."""

    def move(self, goals: Mapping[str, float], pose: str | None, now: float) -> None:
        """Head for ``goals``; :class:`ArmError` says why it cannot."""

    def settled(self, now: float) -> bool:
        """The last move has arrived."""

    def stopped(self) -> str | None:
        """Why the arm cannot move (e-stop freeze, fault), or None."""


@dataclass(frozen=True)
class ArmStep:
    """One arm move of the sequence: its name in the status, the joint goals, the pose name."""

    name: str
    goals: dict[str, float]
    pose: str | None = None


def standoffs(target: tuple[float, float], reach: float, robot: Pose2,
              free: Callable[[float, float], bool], count: int) -> list[Pose2]:
    """Up to ``count`` poses ``reach`` from ``target`` facing it (every 22.5°), where the robot
    may stand, nearest the robot first."""
    poses = []
    for k in range(HEADINGS):
        a = 2 * math.pi * k / HEADINGS
        x, y = target[0] + reach * math.cos(a), target[1] + reach * math.sin(a)
        if free(x, y):
            poses.append((x, y, math.remainder(a + math.pi, math.tau)))
    poses.sort(key=lambda p: math.hypot(p[0] - robot[0], p[1] - robot[1]))
    return poses[:count]


@dataclass
class FetchSequence:
    """IDLE -> NAV_TO_OBJECT -> GRASP -> NAV_TO_DROP -> DELIVER -> IDLE. Handed the time by
    :meth:`tick` (each control tick), never reads a clock. ``held`` says whether the object is
    in the gripper (None: no sensor, assumed held). A failure cancels navigation and sends the
    arm to ``home`` unless the e-stop or a fault froze it."""

    nav: Navigation
    arm: Arm
    held: Callable[[], bool | None]
    grasp_reach: float
    drop_reach: float
    grasp_steps: list[ArmStep]
    deliver_steps: list[ArmStep]
    safe_step: ArmStep
    approaches: int = 3
    #: what the sensor (the simulator) says about a miss, for the reason
    miss_detail: Callable[[], str] = lambda: ""
    state: str = IDLE
    result: str = ""  # "", running, succeeded, failed, canceled
    reason: str = ""
    step: str = ""
    object: tuple[float, float] | None = None
    drop: tuple[float, float] | None = None
    fetches: int = 0
    started: float = 0.0
    ended: float | None = None
    times: dict[str, float] = field(default_factory=dict)
    _entered: float = 0.0
    _candidates: list[Pose2] = field(default_factory=list)
    _attempts: list[str] = field(default_factory=list)
    _arm_index: int = 0
    _arm_sent: bool = False
    _faced: bool = False

    @property
    def active(self) -> bool:
        return self.state != IDLE

    # -- starting and stopping ---------------------------------------------------------------

    def start(self, obj: tuple[float, float], drop: tuple[float, float], now: float) -> None:
        if self.active:
            raise FetchError(f"a fetch is running ({self.state}): DELETE /api/fetch first")
        candidates = self._standoffs(obj, self.grasp_reach)
        if not candidates:
            raise FetchError(f"object: no free pose {self.grasp_reach:.3f} m from "
                             f"({obj[0]:.2f}, {obj[1]:.2f}) for the robot to grasp from")
        self.object, self.drop = obj, drop
        self.fetches += 1
        self.result, self.reason, self.started, self.ended = "running", "", now, None
        self.times = {}
        self._attempts = []
        self._candidates = candidates
        self._enter(NAV_TO_OBJECT, now)
        self._next_approach(now)

    def _standoffs(self, target: tuple[float, float], reach: float) -> list[Pose2]:
        return standoffs(target, reach, self.nav.pose(), self.nav.free, self.approaches)

    def cancel(self, reason: str, now: float) -> bool:
        if not self.active:
            return False
        self._finish("canceled", reason, now)
        return True

    def fail(self, reason: str, now: float) -> None:
        if self.active:
            self._finish("failed", reason, now)

    def _finish(self, result: str, reason: str, now: float) -> None:
        self.times[self.state] = self.times.get(self.state, 0.0) + now - self._entered
        ending_in = self.state
        self.state, self.step = IDLE, ""
        self.result, self.ended = result, now
        if result == "succeeded":
            self.reason = reason
            return
        if self.nav.outcome() is None:
            self.nav.cancel(f"fetch {result}")
        stopped = self.arm.stopped()
        if stopped is not None:
            safe = f"the arm holds where it is ({stopped})"
        else:
            try:
                self.arm.move(self.safe_step.goals, self.safe_step.pose, now)
                safe = f"the arm goes to {self.safe_step.name}"
            except ArmError as exc:
                safe = f"the arm holds where it is ({exc})"
        self.reason = f"{ending_in}: {reason}; navigation stopped, {safe}"

    def _enter(self, state: str, now: float) -> None:
        if self.state != IDLE:
            self.times[self.state] = self.times.get(self.state, 0.0) + now - self._entered
        self.state, self._entered, self.step = state, now, ""
        self._arm_index, self._arm_sent, self._faced = 0, False, False

    # -- the tick ----------------------------------------------------------------------------

    def tick(self, now: float, estop: str | None) -> None:
        if not self.active:
            return
        if estop is not None:
            self.fail(f"e-stop engaged ({estop})", now)
            return
        if self.state in (NAV_TO_OBJECT, NAV_TO_DROP):
            self._navigating(now)
        else:
            self._arm_sequence(now)

    def _next_approach(self, now: float) -> None:
        while self._candidates:
            x, y, yaw = self._candidates.pop(0)
            self.step = f"standoff ({x:.2f}, {y:.2f})"
            try:
                self.nav.go(x, y, yaw)
                return
            except ValueError as exc:
                self._attempts.append(f"({x:.2f}, {y:.2f}) refused: {exc}")
        what = "object" if self.state == NAV_TO_OBJECT else "drop point"
        self.fail(f"cannot reach the {what}: " + "; ".join(self._attempts), now)

    def _navigating(self, now: float) -> None:
        outcome = self.nav.outcome()
        if self.state == NAV_TO_DROP and self.held() is False:
            self.fail("the object is no longer held", now)
            return
        if outcome is None:
            return
        state, reason = outcome
        if state == "succeeded" and not self._faced:
            self._face(now)
            return
        if state != "failed" and state != "succeeded":  # canceled: a client took over
            self.fail(f"navigation {state}: {reason}", now)
            return
        if state == "succeeded" or self._faced:  # a face goal that failed: grasp from here
            self._arrived(now)
            return
        self._attempts.append(f"{self.step}: {reason}")
        self._next_approach(now)

    def _arrived(self, now: float) -> None:
        self._enter(GRASP if self.state == NAV_TO_OBJECT else DELIVER, now)
        self._attempts = []
        self._arm_sequence(now)

    def _face(self, now: float) -> None:
        """At the standoff: one more goal where the robot stands (within the tolerance of the
        point ``reach`` from the target on the line through the robot), turned to face the
        target from there, so that the tool point's error is along the arm, not across it."""
        self._faced = True
        target = self.object if self.state == NAV_TO_OBJECT else self.drop
        reach = self.grasp_reach if self.state == NAV_TO_OBJECT else self.drop_reach
        assert target is not None
        x, y, _ = self.nav.pose()
        bearing = math.atan2(target[1] - y, target[0] - x)
        self.step = "face " + ("the object" if self.state == NAV_TO_OBJECT else "the drop point")
        try:
            self.nav.go(target[0] - reach * math.cos(bearing),
                        target[1] - reach * math.sin(bearing), bearing,
                        (FACE_XY_M, FACE_YAW_RAD))
        except ValueError:  # (too near an obstacle for a goal): grasp from where it stands
            self._arrived(now)

    def _arm_sequence(self, now: float) -> None:
        steps = self.grasp_steps if self.state == GRASP else self.deliver_steps
        stopped = self.arm.stopped()
        if stopped is not None:
            self.fail(f"the arm stopped: {stopped}", now)
            return
        if self._arm_sent and not self.arm.settled(now):
            return
        if self._arm_sent:  # the step arrived
            problem = self._after(steps[self._arm_index].name)
            if problem:
                self.fail(problem, now)
                return
            self._arm_index, self._arm_sent = self._arm_index + 1, False
        if self._arm_index == len(steps):
            self._arm_done(now)
            return
        step = steps[self._arm_index]
        self.step = step.name
        try:
            self.arm.move(step.goals, step.pose, now)
        except ArmError as exc:
            self.fail(f"the arm refused {step.name}: {exc}", now)
            return
        self._arm_sent = True

    def _after(self, step: str) -> str:
        """What is wrong once ``step`` arrived (the object not in the gripper), or ''."""
        held = self.held()
        if self.state == GRASP and step == "grasp_close" and held is False:
            detail = self.miss_detail()
            return ("the object is not held after grasp_close (it was not between the fingers"
                    + (f": {detail}" if detail else "") + ")")
        if self.state == DELIVER and step == "open" and held is True:
            return "the object is still held after opening the gripper"
        return ""

    def _arm_done(self, now: float) -> None:
        if self.state == GRASP:
            assert self.drop is not None
            candidates = self._standoffs(self.drop, self.drop_reach)
            self._enter(NAV_TO_DROP, now)
            if not candidates:
                self.fail(f"drop: no free pose {self.drop_reach:.3f} m from "
                          f"({self.drop[0]:.2f}, {self.drop[1]:.2f}) to put it down from", now)
                return
            self._candidates = candidates
            self._next_approach(now)
            return
        self._finish("succeeded", "", now)

    # -- reports -----------------------------------------------------------------------------

    def status(self, now: float) -> dict[str, Any]:
        out: dict[str, Any] = {"state": self.state, "step": self.step, "result": self.result,
                               "reason": self.reason, "fetches": self.fetches}
        if self.object is not None and self.drop is not None:
            out["object"] = [round(v, 3) for v in self.object]
            out["drop"] = [round(v, 3) for v in self.drop]
            end = self.ended if self.ended is not None else now
            out["elapsed_s"] = round(max(0.0, end - self.started), 2)
            out["state_times_s"] = {k: round(v, 2) for k, v in self.times.items()}
        out["held"] = self.held()
        return out
