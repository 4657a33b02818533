# The "fetch" component: POST/GET/DELETE /api/fetch, /fetch/state; drives navigation and the arm.
from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from aiohttp import web

from daemon import coords
from daemon.bus import BusKey
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, Plugs, Route
from daemon.components.arm.component import ArmComponent
from daemon.components.arm.controller import ArmController, ArmRefused
from daemon.components.arm.kinematics import forward
from daemon.components.fetch.sequence import ArmError, ArmStep, FetchError, FetchSequence, Pose2
from daemon.components.fetch.settings import FetchSettings
from daemon.components.navigation.component import NavigationComponent
from daemon.components.navigation.messages import GoalRequest
from daemon.health import Health
from daemon.messages.convert import json_string_msg
from daemon.messages.definitions import STRING
from daemon.robot import RobotBase
from daemon.state_publisher import StatePublisher
from daemon.topics import Topic, TopicOut
from daemon.web import ApiError, json_response, read_json_object

log = logging.getLogger("arbiterd.fetch")

#: the fetch's state on every change and once a second
STATE: BusKey[dict[str, Any]] = BusKey("fetch_state")
#: cells this near the object's centre are the object itself, not an obstacle beside it (m)
OBJECT_CELLS_M = 0.12


class NavigationLink:
    """The fetch's view of the navigation component: goals in its frame, their outcome."""

    def __init__(self, nav: NavigationComponent) -> None:
        self.nav = nav
        self.goal: int | None = None

    def go(self, x: float, y: float, yaw: float,
           tolerances: tuple[float, float] | None = None) -> None:
        xy, turn = tolerances or (None, None)
        self.nav.request(GoalRequest(self.nav.frame, x, y, yaw, xy_tolerance=xy,
                                     yaw_tolerance=turn))
        self.goal = self.nav.navigator.goals

    def outcome(self) -> tuple[str, str] | None:
        navigator = self.nav.navigator
        if self.goal is None:
            return ("canceled", "no goal")
        if navigator.goals != self.goal:
            return ("canceled", "replaced by another goal")
        return None if navigator.active else (navigator.state, navigator.reason)

    def cancel(self, reason: str) -> None:
        if self.outcome() is None:
            self.nav.cancel(reason)

    def pose(self) -> Pose2:
        return self.nav.pose()

    def free(self, x: float, y: float) -> bool:
        """No cell within one cell of (x, y) is lethal as far as the lidar saw (so that the
        goal facing the object, within a few cm of it, is not refused either)."""
        area = self.nav.area
        row, col = area.cell(x, y)
        if not (area.inside(row - 1, col - 1) and area.inside(row + 1, col + 1)):
            return False
        costs = self.nav.refresh_costs()
        if costs is None:
            return True
        block = costs[row - 1:row + 2, col - 1:col + 2]
        seen = self.nav.costmap.seen[row - 1:row + 2, col - 1:col + 2]
        return bool(np.isfinite(block[seen]).all())

    def obstacle_near(self, x: float, y: float, beyond: float, within: float) -> float | None:
        """The distance to the nearest seen obstacle cell between ``beyond`` and ``within``
        of (x, y), or None."""
        self.nav.refresh_costs()
        costmap, area = self.nav.costmap, self.nav.area
        cells = costmap.obstacles() & costmap.seen
        reach = math.ceil(within / area.resolution) + 1
        row, col = area.cell(x, y)
        r0, r1 = max(0, row - reach), min(area.height, row + reach + 1)
        c0, c1 = max(0, col - reach), min(area.width, col + reach + 1)
        rows, cols = np.nonzero(cells[r0:r1, c0:c1])
        if not len(rows):
            return None
        cx = area.origin_x + (cols + c0 + 0.5) * area.resolution
        cy = area.origin_y + (rows + r0 + 0.5) * area.resolution
        d = np.hypot(cx - x, cy - y)
        d = d[(d > beyond) & (d <= within)]
        return float(d.min()) if len(d) else None


class ArmLink:
    """The fetch's view of the arm controller."""

    def __init__(self, arm: ArmController, connected: Callable[[], str | None]) -> None:
        self.arm = arm
        self.connected = connected

    def move(self, goals: Mapping[str, float], pose: str | None, now: float) -> None:
        try:
            self.arm.command(goals, now, pose=pose)
        except ArmRefused as exc:
            raise ArmError(exc.reason) from None

    def settled(self, now: float) -> bool:
        return not self.arm.motion.moving(now)

    def stopped(self) -> str | None:
        estop = self.arm.frozen_by or self.arm.estop()
        if estop is not None:
            return f"frozen by the e-stop ({estop})"
        if self.arm.fault:
            return f"arm fault: {self.arm.fault}"
        return self.connected()


def arm_steps(arm: ArmController) -> tuple[list[ArmStep], list[ArmStep], ArmStep]:
    """The grasp (pregrasp, grasp, grasp_close, carry), the delivery (pregrasp's joints with
    the gripper still closed, open, home) and the safe pose (home), from the arm's poses."""
    poses, gripper = arm.poses, arm.joints[3]
    grasp = [ArmStep(name, poses[name], name)
             for name in ("pregrasp", "grasp", "grasp_close", "carry")]
    deliver = [ArmStep("pregrasp", {**poses["pregrasp"], gripper: poses["carry"][gripper]}),
               ArmStep("open", {gripper: poses["pregrasp"][gripper]}),
               ArmStep("home", poses["home"], "home")]
    return grasp, deliver, ArmStep("home", poses["home"], "home")


def reach_of(pose: Mapping[str, float], joints: Sequence[str]) -> float:
    """How far ahead of base_link's origin the tool point is at ``pose`` (m)."""
    return forward(pose[joints[0]], pose[joints[1]], pose[joints[2]]).x


def point_of(body: Mapping[str, Any], key: str) -> tuple[float, float]:
    if key not in body:
        raise FetchError(f"{key}: missing (give \"object\": [x, y] and \"drop\": [x, y])")
    value = body[key]
    if not isinstance(value, list) or len(value) != 2:
        raise FetchError(f"{key}: expected [x, y], got {value!r}")
    try:
        return coords.point(value, (f"{key}[0]", f"{key}[1]"))
    except coords.CoordinateError as exc:
        raise FetchError(str(exc)) from None


class FetchComponent(BaseComponent):
    """Runs :class:`FetchSequence` in the control tick over the navigation component (every
    drive goes through it: arbiter, collision monitor, limiter) and the arm's controller."""

    name = "fetch"
    core = False

    def __init__(self, settings: FetchSettings, plugs: Plugs, *,
                 nav: NavigationComponent | None, arm: ArmController | None,
                 arm_connected: Callable[[], str | None] = lambda: None,
                 held: Callable[[], bool | None] = lambda: None,
                 miss: Callable[[], str] = lambda: "") -> None:
        self.settings = settings
        self.robot: RobotBase = plugs.robot
        self.clock = self.robot.clock
        self.nav, self.arm = nav, arm
        self.held = held
        self.link: NavigationLink | None = NavigationLink(nav) if nav is not None else None
        self.sequence: FetchSequence | None = None
        if self.link is not None and arm is not None:
            grasp, deliver, safe = arm_steps(arm)
            joints = arm.joints
            self.sequence = FetchSequence(
                self.link, ArmLink(arm, arm_connected), held,
                reach_of(arm.poses["grasp"], joints), reach_of(arm.poses["pregrasp"], joints),
                grasp, deliver, safe, settings.approaches, miss)
        self._last_state = ""
        self.hooks = plugs.while_busy(on_tick=self._tick, on_command=self._on_command)
        plugs.add_status("fetch", self.brief)
        self.publisher = StatePublisher(plugs, STATE, self.status)

    # -- requests ----------------------------------------------------------------------------

    def refusal(self) -> str | None:
        if self.arm is None:
            return "the fetch needs the arm: set [arm] enabled = true"
        if self.nav is None:
            return "the fetch needs navigation: set [navigation] enabled = true"
        return self.nav.refusal()

    def request(self, obj: tuple[float, float], drop: tuple[float, float]) -> None:
        """Start a fetch; FetchError says why it cannot."""
        refusal = self.refusal()
        if refusal:
            raise FetchError(refusal)
        assert self.sequence is not None and self.link is not None
        clearance = self.settings.object_clearance_m
        for what, (x, y) in (("object", obj), ("drop", drop)):
            area = self.link.nav.area
            if not area.inside(*area.cell(x, y)):
                raise FetchError(f"{what}: ({x:.2f}, {y:.2f}) is outside the map "
                                 f"([navigation] size_m)")
            near = self.link.obstacle_near(x, y, OBJECT_CELLS_M if what == "object" else -1.0,
                                           clearance)
            if near is not None:
                raise FetchError(f"{what}: ({x:.2f}, {y:.2f}) is inside or against an obstacle "
                                 f"(one {near:.2f} m away; [fetch] object_clearance_m = "
                                 f"{clearance:g})")
        now = self.clock()
        self.sequence.start(obj, drop, now)
        self.hooks.start()
        log.info("fetch %d: object (%.2f, %.2f) to (%.2f, %.2f)", self.sequence.fetches,
                 *obj, *drop)
        self._changed(now)

    def cancel(self, reason: str) -> bool:
        if self.sequence is None:
            return False
        done = self.sequence.cancel(reason, self.clock())
        if done:
            self._changed(self.clock())
        return done

    def _on_command(self, source: str) -> None:
        """A client's command (teleop) ends the fetch as it ends a navigation goal."""
        if self.sequence is not None and self.sequence.active:
            self.cancel(f"teleop from {source}")
        else:
            self.hooks.stop()

    # -- the tick ----------------------------------------------------------------------------

    def _tick(self, now: float, on_time: bool) -> None:
        sequence = self.sequence
        if sequence is None or not sequence.active:
            self.hooks.stop()
            return
        robot = self.robot
        estop = (robot.estop_reason or "latched") if robot.estop_engaged else None
        if estop is None and self.robot.fault:
            estop = f"driver fault: {self.robot.fault}"
        sequence.tick(now, estop)
        self._changed(now)

    def _changed(self, now: float) -> None:
        assert self.sequence is not None
        key = f"{self.sequence.state}/{self.sequence.step}/{self.sequence.result}"
        if key != self._last_state:
            if self.sequence.result in ("failed", "canceled") and not self.sequence.active:
                log.warning("fetch %d %s: %s", self.sequence.fetches, self.sequence.result,
                            self.sequence.reason)
            self._last_state = key
            self.publisher.publish(now)

    # -- reports -----------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        if self.sequence is None:
            return {"state": "IDLE", "available": False, "reason": self.refusal()}
        return {**self.sequence.status(self.clock()), "available": True}

    def brief(self) -> dict[str, Any]:
        status = self.status()
        return {k: status[k] for k in ("state", "step", "result", "reason") if k in status}

    def health(self) -> Health:
        if self.sequence is None:  # nothing wrong with the robot: fetches are refused, saying why
            return Health("ok", self.refusal() or "cannot fetch", self.brief())
        return Health("ok", values=self.brief())

    # -- HTTP and topics ---------------------------------------------------------------------

    def routes(self) -> Sequence[Route]:
        return (Route("GET", "/api/fetch", self.get_fetch, "read"),
                Route("POST", "/api/fetch", self.post_fetch, "drive"),
                Route("DELETE", "/api/fetch", self.delete_fetch, "drive"))

    def topics(self) -> Sequence[Topic]:
        return (TopicOut("/fetch/state", STRING, STATE, json_string_msg, "on change + 1 Hz"),)

    async def get_fetch(self, request: web.Request) -> web.Response:
        return json_response(self.status())

    async def post_fetch(self, request: web.Request) -> web.Response:
        body = await read_json_object(request, 4096)
        unknown = sorted(set(body) - {"object", "drop"})
        try:
            if unknown:
                raise FetchError(f"{unknown[0]}: unknown field (object, drop)")
            obj, drop = point_of(body, "object"), point_of(body, "drop")
        except FetchError as exc:
            raise ApiError(422, f"invalid fetch: {exc}") from None
        try:
            self.request(obj, drop)
        except FetchError as exc:
            raise ApiError(409, f"fetch refused: {exc}") from None
        return json_response(self.status())

    async def delete_fetch(self, request: web.Request) -> web.Response:
        self.cancel("canceled over HTTP")
        return json_response(self.status())

    async def stop(self) -> None:
        self.cancel("daemon stopping")


def create(ctx: DaemonContext) -> FetchComponent | None:
    """The fetch component when ``[fetch] enabled``; it refuses fetches (saying which section
    to enable) when the arm or navigation is off."""
    settings = ctx.settings(FetchSettings)
    if not settings.enabled:
        return None
    nav = ctx.components.get("navigation")
    arm = ctx.components.get("arm")
    arm_component = arm if isinstance(arm, ArmComponent) else None
    held: Callable[[], bool | None] = lambda: None  # noqa: E731 - no sensor: assumed held
    miss: Callable[[], str] = lambda: ""  # noqa: E731
    if ctx.sim is not None:
        objects = ctx.sim.world.objects
        held, miss = (lambda: objects.held is not None), objects.miss
    return FetchComponent(
        settings, ctx.plugs, nav=nav if isinstance(nav, NavigationComponent) else None,
        arm=arm_component.arm if arm_component is not None else None,
        arm_connected=(lambda: arm_component.unreachable) if arm_component else lambda: None,
        held=held, miss=miss)


COMPONENT = ComponentSpec("fetch", create, FetchSettings)
