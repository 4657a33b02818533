# The arm's state machine: checked targets -> joint-space moves -> servo writes; e-stop and faults.
from __future__ import annotations

import logging
import math
from collections.abc import Awaitable, Callable, Mapping
from typing import Any

from daemon.components.arm.kinematics import forward
from daemon.components.arm.motion import JointMotion
from daemon.components.arm.settings import ArmSettings
from drivers.devices import DeviceError
from drivers.servo_array import ServoArray

log = logging.getLogger("arbiterd.arm")

#: a finished move and a pose agree within this much (rad, m)
AT_POSE = 1e-6
#: what a shutdown's park at home may take before the arm holds where it got to, s
PARK_LIMIT_S = 2.5


class ArmRefused(Exception):
    """A command the arm does not take: ``status`` is the HTTP status that says why."""

    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.reason = reason


class ArmController:
    """The arm between its commands and its servos. :meth:`command` checks targets (known
    joints, finite, inside the limits: a refusal names the joint) and starts a move from where
    the arm is; :meth:`step` (called at the servo rate, handed the time) writes where the move
    has got to, only when that changed, since a servo holds its last pulse. ``estop`` says why
    the e-stop is latched (None: it is not); while it is, the arm stays frozen where it was and
    commands are refused. A device fault freezes it too."""

    def __init__(self, settings: ArmSettings, servo: ServoArray, now: float,
                 estop: Callable[[], str | None] = lambda: None) -> None:
        self.settings = settings
        self.servo = servo
        self.estop = estop
        self.joints = list(settings.joints)
        self.limits = {j: (lo, hi) for j, lo, hi in
                       zip(self.joints, settings.lower, settings.upper, strict=True)}
        self.poses = settings.named_poses()
        self.motion = JointMotion(dict(zip(self.joints, settings.max_speed, strict=True)),
                                  self.poses["home"], now)
        self.target_pose: str | None = "home"
        self.fault: str | None = None
        self.frozen_by: str | None = None
        self.written: dict[str, float] | None = None
        self.writes = 0
        self.steps = 0

    # -- commands ----------------------------------------------------------------------------

    def command(self, goals: Mapping[str, Any], now: float, pose: str | None = None) -> float:
        """Check ``goals`` (joint => position) and head there; returns the move's duration."""
        self._check_ready()
        checked = {name: self._checked(name, value) for name, value in goals.items()}
        duration = self.motion.move_to(checked, now)
        self.target_pose = pose if pose is not None else self._pose_named(self.motion.goal)
        return duration

    def go_to_pose(self, name: str, now: float) -> float:
        if name not in self.poses:
            raise ArmRefused(404, f"no pose named {name!r}; poses: {', '.join(self.poses)}")
        return self.command(self.poses[name], now, pose=name)

    def _check_ready(self) -> None:
        reason = self.estop()
        if reason is not None:
            raise ArmRefused(409, f"e-stop engaged ({reason}): the arm holds where it is")
        if self.fault:
            raise ArmRefused(503, f"arm fault: {self.fault}")
        if not self.servo.is_open:
            raise ArmRefused(503, "the arm's servos are not connected")

    def _checked(self, name: str, value: Any) -> float:
        if name not in self.limits:
            raise ArmRefused(422, f"unknown joint {name!r}; joints: {', '.join(self.joints)}")
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(value):
            raise ArmRefused(422, f"{name}: expected a finite number, got {value!r}")
        low, high = self.limits[name]
        if not low <= value <= high:
            raise ArmRefused(422, f"{name} = {value} is outside its limits {low}..{high}")
        return float(value)

    # -- the servo rate ----------------------------------------------------------------------

    async def step(self, now: float, *, obey_estop: bool = True) -> None:
        """Write where the move is at ``now`` (frozen first when the e-stop is latched)."""
        self.steps += 1
        reason = self.estop() if obey_estop else None
        if reason is not None and self.frozen_by is None:
            self.frozen_by = reason
            self.motion.freeze(now)
            log.warning("arm frozen: e-stop (%s)", reason)
        elif reason is None and obey_estop:
            self.frozen_by = None
        here = self.motion.position(now)
        if self.fault or not self.servo.is_open or here == self.written:
            return
        try:
            await self.servo.write(here)
        except DeviceError as exc:
            self.fail(str(exc), now)
            return
        self.written, self.writes = here, self.writes + 1

    def fail(self, reason: str, now: float) -> None:
        self.fault = reason
        self.motion.freeze(now)
        log.error("arm fault: %s", reason)

    async def park_or_relax(self, clock: Callable[[], float],
                            sleep: Callable[[float], Awaitable[None]]) -> str:
        """The shutdown: ``on_stop = "home"`` parks at home (at the speed limits, within
        ``PARK_LIMIT_S``) and holds it, unless an e-stop froze the arm before the shutdown
        or the servos failed; else (and for ``relax``) the pulses go off. Says which."""
        user_estop = self.frozen_by not in (None, "shutdown")
        if self.settings.on_stop == "home" and not user_estop and not self.fault \
                and self.servo.is_open:
            start = clock()
            self.motion.move_to(self.poses["home"], start)
            period = 1.0 / self.settings.update_rate
            while clock() - start < PARK_LIMIT_S and self.motion.moving(clock()):
                await self.step(clock(), obey_estop=False)
                await sleep(period)
            await self.step(min(clock(), self.motion.arrival()), obey_estop=False)
            return "parked at home" if not self.motion.moving(clock()) else "parking cut short"
        await self.servo.relax()
        return "relaxed"

    # -- reports -----------------------------------------------------------------------------

    def _pose_named(self, positions: Mapping[str, float]) -> str | None:
        for name, pose in self.poses.items():
            if all(abs(positions[j] - pose[j]) <= AT_POSE for j in self.joints):
                return name
        return None

    def pose_at(self, now: float) -> str | None:
        """The named pose the arm is at (standing still), or None."""
        if self.motion.moving(now):
            return None
        here = self.motion.position(now)
        if self.target_pose is not None and all(
                abs(here[j] - self.poses[self.target_pose][j]) <= AT_POSE for j in self.joints):
            return self.target_pose
        return self._pose_named(here)

    def state(self, now: float,
              measured: Mapping[str, float | None] | None = None) -> dict[str, Any]:
        here, goal = self.motion.position(now), self.motion.goal
        joints: dict[str, dict[str, float | None]] = {}
        for name in self.joints:
            low, high = self.limits[name]
            joints[name] = {"position": round(here[name], 6), "target": round(goal[name], 6),
                            "lower": low, "upper": high}
            if measured is not None:
                value = measured.get(name)
                joints[name]["measured"] = None if value is None else round(value, 6)
        j1, j2, j3, gripper = self.joints
        tip = forward(here[j1], here[j2], here[j3])
        return {"backend": self.settings.backend, "moving": self.motion.moving(now),
                "pose": self.pose_at(now), "target_pose": self.target_pose,
                "joints": joints, "gripper_m": round(here[gripper], 6),
                "end_effector": {"frame_id": "base_link", **tip.to_json()},
                "frozen_by_estop": self.frozen_by, "fault": self.fault,
                "poses": sorted(self.poses)}
