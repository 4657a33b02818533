# The "dock" component: the dock's pose, going home (navigation, V fit, final approach), leaving.
from __future__ import annotations

import json
import logging
import math
import os
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

from aiohttp import web

from daemon.bus import BusKey
from daemon.commands import Twist
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, Plugs, Route
from daemon.components.battery.component import BatteryComponent
from daemon.components.dock.approach import (
    SETTLE_M,
    DockEstimate,
    align_twist,
    approach_twist,
)
from daemon.components.dock.settings import DockSettings
from daemon.components.fetch.component import FetchComponent
from daemon.components.navigation.component import NavigationComponent
from daemon.components.navigation.messages import GoalRequest
from daemon.health import Health
from daemon.messages.convert import json_string_msg
from daemon.messages.definitions import STRING
from daemon.paths import state_directory
from daemon.robot import RobotBase
from daemon.state_publisher import StatePublisher
from daemon.telemetry import SCAN
from daemon.topics import Inbound, Refusal, Topic, TopicIn, TopicOut
from daemon.web import ApiError, json_response, read_json_object
from nav.dock import DockShape, fit_v
from sensors.scan import LaserScan, ScanPoints
from slam.pose import Pose2, between, compose

log = logging.getLogger("arbiterd.dock")

SOURCE = "dock"
#: as navigation: below every client, above the wander behaviour
PRIORITY = 1
STATE: BusKey[dict[str, Any]] = BusKey("dock_state")
IDLE, NAVIGATING, SEARCHING, APPROACHING, SETTLING, FINAL, CONFIRMING, DOCKED, BACKING, \
    UNDOCKING = ("IDLE", "NAVIGATING", "SEARCHING", "APPROACHING", "SETTLING", "FINAL",
                 "CONFIRMING", "DOCKED", "BACKING", "UNDOCKING")
MOVING = (NAVIGATING, SEARCHING, APPROACHING, SETTLING, FINAL, CONFIRMING, BACKING,
          UNDOCKING)
#: on the way in: states whose revolutions are fitted, and those with the dock as the goal
FITTING = (SEARCHING, APPROACHING, SETTLING)
TOUCHING = (APPROACHING, SETTLING, FINAL, CONFIRMING)
#: short of the dock, standing still this long to average the fits (s)
SETTLE_S = 2.5
#: fits in a row needed at the staging pose before the approach starts
FITS_TO_START = 3
#: lidar points this near the dock's arms (4 sigma of the simulated lidar's noise) are the goal,
#: not obstacles, on the way in (m)
GOAL_BAND_M = 0.08
#: an approach that failed backs out this far before trying again (m)
RETRY_BACK_M = 0.3
#: backing speed (m/s)
BACK_SPEED = 0.1
#: after a failed automatic homing, the power policy waits this long before trying again (s)
AUTO_RETRY_S = 60.0


class GoalZone(Protocol):
    """The collision monitor, told what the robot is meant to touch."""

    def set_goal_zone(self, segments: list[tuple[float, float, float, float]] | None,
                      band: float = 0.0) -> None: ...


class DockError(ValueError):
    """Going home or leaving cannot start, with the reason."""


def parse_pose(body: dict[str, Any], frame: str) -> tuple[str, Pose2] | None:
    """``{"here": true}`` (None) or ``{"x", "y", "theta"[, "frame"]}``; DockError names the
    field."""
    allowed = {"here", "x", "y", "theta", "frame"}
    unknown = sorted(set(body) - allowed)
    if unknown:
        raise DockError(f"{unknown[0]}: unknown field (here, or x, y, theta, frame)")
    if "here" in body:
        if body["here"] is not True or len(body) > 1:
            raise DockError("here: expected true, alone (the robot stands docked now)")
        return None
    values = []
    for key in ("x", "y", "theta"):
        if key not in body:
            raise DockError(f"{key}: missing (give \"here\": true, or x, y and theta)")
        v = body[key]
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
                or abs(v) > 1e4:
            raise DockError(f"{key}: expected a finite number (|x| <= 10000), got {v!r}")
        values.append(float(v))
    given = body.get("frame", frame)
    if not isinstance(given, str) or not given or len(given) > 64:
        raise DockError(f"frame: expected a frame name, got {given!r}")
    return given, (values[0], values[1], math.remainder(values[2], math.tau))


class DockComponent(BaseComponent):
    """Going home: navigation to the staging pose in front of the dock, the V found in the
    lidar's revolutions, a final approach through the arbiter (the collision monitor told
    that the dock's arms are the goal), contact confirmed by the battery's current. Leaving:
    backing out. The power policy: at low charge home when the current task ends, at very low
    at once."""

    name = "dock"
    core = False

    def __init__(self, settings: DockSettings, plugs: Plugs, *,
                 nav: NavigationComponent | None, guard: GoalZone | None,
                 battery: BatteryComponent | None, fetch: FetchComponent | None = None,
                 points: ScanPoints, footprint_radius: float, store: Path | None,
                 wall_clock: Callable[[], float] = time.time) -> None:
        self.settings = settings
        self.robot: RobotBase = plugs.robot
        self.clock = self.robot.clock
        self.wall_clock = wall_clock
        self.nav, self.guard, self.battery, self.fetch = nav, guard, battery, fetch
        self.points = points
        self.shape = DockShape(settings.arm_m, settings.opening_deg, settings.clearance_m,
                               footprint_radius)
        self.store = store
        #: the dock: the robot's pose when docked, in a frame of navigation's
        self.dock: tuple[str, Pose2] | None = self._load()
        self.state, self.result, self.reason = IDLE, "", ""
        self.estimate = DockEstimate()
        self.homings = self.dockings = self.attempts = 0
        self.started = self.entered = 0.0
        self.auto = ""  # why the power policy sent it home ("" : asked)
        self._auto_failed = -math.inf
        self._own_request = False
        self._retries_left = 0
        self._back_from: Pose2 | None = None
        self._stopped_reads = 0
        self._history: deque[tuple[float, Pose2]] = deque(maxlen=200)
        self.last_error: tuple[float, float] | None = None
        self.hooks = plugs.while_busy(tick_source=self._tick, on_command=self._on_command)
        plugs.subscribe(SCAN, self.on_scan)
        plugs.add_status("dock", self.brief)
        if battery is not None and settings.go_home:
            plugs.schedule(self._policy)
        self.publisher = StatePublisher(plugs, STATE, self.status)

    # -- the dock's pose -----------------------------------------------------------------------

    def _load(self) -> tuple[str, Pose2] | None:
        if self.store is None:
            return None
        try:
            if not self.store.is_file():  # may raise: a folder this user may not look into
                return None
            data = json.loads(self.store.read_text())
            pose = (float(data["x"]), float(data["y"]), float(data["theta"]))
            if not all(math.isfinite(v) for v in pose):
                raise ValueError("not finite")
            return str(data["frame"]), pose
        except (OSError, ValueError, KeyError, TypeError) as exc:
            log.error("dock: cannot read %s (%s): no dock known", self.store, exc)
            return None

    def set_dock(self, frame: str, pose: Pose2) -> None:
        self.dock = (frame, pose)
        log.info("dock: at (%.3f, %.3f) %.1f deg in %s", pose[0], pose[1],
                 math.degrees(pose[2]), frame)
        if self.store is None:
            return
        try:
            self.store.parent.mkdir(parents=True, exist_ok=True)
            temporary = self.store.with_suffix(".tmp")
            temporary.write_text(json.dumps({"frame": frame, "x": pose[0], "y": pose[1],
                                             "theta": pose[2]}))
            os.replace(temporary, self.store)
        except OSError as exc:  # the dock is known until the next start
            log.error("dock: cannot keep the dock's pose in %s (%s): set [dock] file to a "
                      "folder this user may write", self.store, exc)

    def set_here(self) -> Pose2:
        """The robot stands docked now: its pose is the dock's."""
        if self.nav is None:
            raise DockError("setting the dock needs navigation: set [navigation] enabled")
        pose = self.nav.pose()
        self.set_dock(self.nav.frame, pose)
        return pose

    def _dock_in_nav(self) -> Pose2:
        assert self.nav is not None and self.dock is not None
        frame, (x, y, theta) = self.dock
        return self.nav.to_frame(frame, x, y, theta)

    # -- requests ------------------------------------------------------------------------------

    @property
    def active(self) -> bool:
        return self.state in MOVING

    @property
    def docked(self) -> bool:
        return self.state == DOCKED

    def refusal(self) -> str | None:
        if self.nav is None:
            return "going home needs navigation: set [navigation] enabled = true"
        if self.dock is None:
            return "no dock known: POST /api/dock with \"here\" while docked, or its pose"
        return None

    def go_home(self, why: str = "") -> None:
        """Start going home; DockError says why it cannot."""
        refusal = self.refusal()
        if refusal:
            raise DockError(refusal)
        if self.state == DOCKED or (self.active and self.state != UNDOCKING):
            return
        assert self.nav is not None
        try:
            staging = self.shape.staging(self._dock_in_nav(), self.settings.staging_m)
        except ValueError as exc:
            raise DockError(str(exc)) from None
        self._own_request = True
        try:
            self.nav.request(GoalRequest(self.nav.frame, *staging))
        except ValueError as exc:
            raise DockError(str(exc)) from None
        finally:
            self._own_request = False
        self.homings += 1
        self.auto = why
        self.started = self.clock()
        self.result, self.reason = "running", ""
        self._retries_left = self.settings.retries
        self._enter(NAVIGATING)
        self.hooks.start()
        log.info("dock: going home%s", f" ({why})" if why else "")

    def leave(self) -> None:
        """Back out of the dock (from DOCKED, or a docking in progress ends)."""
        if self.state == UNDOCKING:
            return
        if self.state not in (DOCKED, *TOUCHING) and not self._near_dock():
            if self.active:
                self.cancel("leave requested")
                return
            raise DockError("not on the dock")
        if self.robot.estop_engaged:
            raise DockError("e-stop engaged: release it first")
        self.result, self.reason = "running", ""
        self._back_from = self.robot.pose_xyt()
        self._enter(UNDOCKING)
        self.hooks.start()

    def _near_dock(self) -> bool:
        if self.dock is None or self.nav is None:
            return False
        try:
            docked = self._dock_in_nav()
        except ValueError:
            return False
        here = self.nav.pose()
        return math.hypot(here[0] - docked[0], here[1] - docked[1]) < 0.1

    def cancel(self, reason: str) -> bool:
        if not self.active:
            return False
        if self.state == NAVIGATING and self.nav is not None:
            self.nav.cancel(f"going home canceled: {reason}")
        self._finish("canceled", reason)
        return True

    def _on_command(self, source: str) -> None:
        if source != SOURCE and self.active:
            self.cancel(f"teleop from {source}")

    def exempt(self) -> bool:
        """The battery's refusal lets the dock's own homing goal through."""
        return self._own_request

    # -- the lidar -----------------------------------------------------------------------------

    def on_scan(self, scan: LaserScan) -> None:
        if self.state not in FITTING or self.estimate.pose is None:
            return
        now = self.clock()
        age = min(max(0.0, self.wall_clock() - scan.stamp), 2.0)
        at = self._odom_at(now - age)
        px, py = self.points(scan)
        fit = fit_v(px, py, between(at, self.estimate.pose), self.shape)
        if fit is None:
            return
        self.estimate.add(compose(at, fit.docked), now)
        if self.state == APPROACHING and self.guard is not None:
            self.guard.set_goal_zone(self.shape.arms(self.estimate.pose), GOAL_BAND_M)

    def _odom_at(self, t: float) -> Pose2:
        for stamp, pose in reversed(self._history):
            if stamp <= t:
                return pose
        return self.robot.pose_xyt()

    # -- the tick ------------------------------------------------------------------------------

    def _enter(self, state: str) -> None:
        self.state, self.entered = state, self.clock()
        self.publisher.publish(self.entered)

    def _tick(self, now: float) -> None:
        odom = self.robot.pose_xyt()
        self._history.append((now, odom))
        if not self.active:
            self.hooks.stop()
            return
        if self.robot.estop_engaged or self.robot.fault:
            why = "e-stop engaged" if self.robot.estop_engaged else \
                f"driver fault: {self.robot.fault}"
            self._finish("failed", why)
            return
        step = {NAVIGATING: self._navigating, SEARCHING: self._searching,
                APPROACHING: self._approaching, SETTLING: self._settling,
                FINAL: self._final, CONFIRMING: self._confirming,
                BACKING: self._backing, UNDOCKING: self._backing}[self.state]
        step(now, odom)

    def _navigating(self, now: float, odom: Pose2) -> None:
        assert self.nav is not None
        navigator = self.nav.navigator
        if navigator.active:
            return
        if navigator.state != "succeeded":
            self._finish("failed", f"navigation to the staging pose {navigator.state}: "
                         f"{navigator.reason}")
            return
        self._search(now, odom)

    def _search(self, now: float, odom: Pose2) -> None:
        """Look for the V where the dock should be (in odometry's frame from here on)."""
        assert self.nav is not None
        guess = compose(odom, between(self.nav.pose(), self._dock_in_nav()))
        self.estimate.reset(guess)
        self.attempts += 1
        self._enter(SEARCHING)

    def _searching(self, now: float, odom: Pose2) -> None:
        self.robot.propose(SOURCE, Twist(0.0, 0.0), now, PRIORITY)
        if self.estimate.fits >= FITS_TO_START:
            assert self.estimate.pose is not None
            if self.guard is not None:
                self.guard.set_goal_zone(self.shape.arms(self.estimate.pose), GOAL_BAND_M)
            self._enter(APPROACHING)
        elif now - self.entered > self.settings.search_s:
            self._finish("failed", f"the lidar did not find the dock's V within "
                         f"{self.settings.search_s:g} s at the staging pose")

    def _approaching(self, now: float, odom: Pose2) -> None:
        estimate = self.estimate
        assert estimate.pose is not None
        if now - estimate.last_fit > self.settings.search_s:
            self._finish("failed", "the lidar lost the dock's V on the way in")
            return
        v, w, remaining = approach_twist(odom, estimate.pose, self.settings.approach_speed)
        if remaining <= SETTLE_M:
            self.robot.propose(SOURCE, Twist(0.0, 0.0), now, PRIORITY)
            estimate.still = []
            self._enter(SETTLING)
            return
        self.robot.propose(SOURCE, Twist(v, w), now, PRIORITY)

    def _settling(self, now: float, odom: Pose2) -> None:
        """Stopped just short: the fits of revolutions taken standing still, averaged."""
        self.robot.propose(SOURCE, Twist(0.0, 0.0), now, PRIORITY)
        if now - self.entered < SETTLE_S:
            return
        if not self.estimate.settle():
            self._finish("failed", "the lidar lost the dock's V just short of it")
            return
        self._enter(FINAL)

    def _final(self, now: float, odom: Pose2) -> None:
        """The last centimetres on odometry, then the heading turned onto the dock's."""
        docked = self.estimate.pose
        assert docked is not None
        v, w, _ = approach_twist(odom, docked, self.settings.approach_speed)
        if v == 0.0 and w == 0.0:
            w = align_twist(odom, docked)
        self.robot.propose(SOURCE, Twist(v, w), now, PRIORITY)
        if v == 0.0 and w == 0.0:
            self._stopped_reads = self.battery.reads if self.battery is not None else 0
            self._enter(CONFIRMING)

    def _confirming(self, now: float, odom: Pose2) -> None:
        self.robot.propose(SOURCE, Twist(0.0, 0.0), now, PRIORITY)
        battery = self.battery
        if battery is None:
            self._docked("no battery monitor: contact not confirmed")
            return
        reading = battery.latest
        if reading is not None and battery.reads > self._stopped_reads + 1 and \
                reading.status != "discharging":
            self._docked("")
            return
        if now - self.entered < self.settings.contact_wait_s:
            return
        if self._retries_left > 0:
            self._retries_left -= 1
            log.warning("dock: no charge after %g s on the dock: backing out to try again",
                        self.settings.contact_wait_s)
            self._back_from = odom
            self._enter(BACKING)
            return
        self._finish("failed", f"no charge on the dock after {self.settings.retries + 1} "
                     "approaches (the battery kept discharging): check the contacts")

    def _backing(self, now: float, odom: Pose2) -> None:
        start = self._back_from
        assert start is not None
        far = RETRY_BACK_M if self.state == BACKING else self.settings.undock_m
        if math.hypot(odom[0] - start[0], odom[1] - start[1]) < far:
            self.robot.propose(SOURCE, Twist(-BACK_SPEED, 0.0), now, PRIORITY)
            return
        if self.state == BACKING:
            self.attempts += 1
            self._enter(SEARCHING)
            return
        self._finish("undocked", "")

    def _docked(self, note: str) -> None:
        self.robot.withdraw(SOURCE)
        assert self.dock is not None and self.nav is not None
        if self.dock[0] == self.nav.odom_frame:  # odometry drifted: the dock is where it is
            self.dock = (self.dock[0], self.nav.pose())
        if self.guard is not None:
            self.guard.set_goal_zone(None)
        self.dockings += 1
        self.result, self.reason = "docked", note
        self.hooks.stop()
        self._enter(DOCKED)
        log.info("dock: docked after %.1f s%s", self.clock() - self.started,
                 f" ({note})" if note else "")

    def _finish(self, result: str, reason: str) -> None:
        self.robot.withdraw(SOURCE)
        if self.guard is not None:
            self.guard.set_goal_zone(None)
        self.result, self.reason = result, reason
        if result == "failed" and self.auto:
            self._auto_failed = self.clock()
        if result == "failed" and self.state in TOUCHING:
            reason += "; backing out"
            self.reason = reason
            self._back_from = self.robot.pose_xyt()
            self._enter(UNDOCKING)
            return
        self.hooks.stop()
        self._enter(IDLE)
        if result in ("failed", "canceled"):
            log.warning("dock: %s: %s", result, reason)

    # -- the power policy ----------------------------------------------------------------------

    def busy(self) -> bool:
        """A task runs: a goal, a mission, an exploration or a fetch."""
        nav, fetch = self.nav, self.fetch
        if nav is not None and (nav.navigator.active or nav.exploring or (
                nav.mission is not None and nav.mission.running)):
            return True
        return fetch is not None and fetch.sequence is not None and fetch.sequence.active

    def _policy(self, now: float) -> float:
        battery = self.battery
        assert battery is not None
        level = battery.level
        if level not in ("low", "very_low") or self.dock is None or self.state == DOCKED \
                or self.active or now - self._auto_failed < AUTO_RETRY_S:
            return now + 1.0
        if level == "low" and self.busy():
            return now + 1.0
        if level == "very_low" and self.busy():
            if self.fetch is not None:
                self.fetch.cancel("battery very low: going home")
            if self.nav is not None:
                if self.nav.exploring:
                    self.nav.stop_exploring("battery very low: going home")
                self.nav.cancel("battery very low: going home")
        try:
            self.go_home(f"battery {level.replace('_', ' ')}")
        except DockError as exc:
            self._auto_failed = now
            log.warning("dock: cannot go home (battery %s): %s", level, exc)
        return now + 1.0

    # -- reports -------------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        now = self.clock()
        dock = None
        if self.dock is not None:
            frame, (x, y, theta) = self.dock
            dock = {"frame": frame, "x": round(x, 4), "y": round(y, 4),
                    "theta": round(theta, 4)}
        out: dict[str, Any] = {"state": self.state, "result": self.result,
                               "reason": self.reason, "dock": dock,
                               "docked": self.state == DOCKED, "auto": self.auto,
                               "homings": self.homings, "dockings": self.dockings,
                               "attempts": self.attempts, "available": self.refusal() is None}
        if self.active:
            out["elapsed_s"] = round(now - self.started, 2)
        if self.estimate.pose is not None and self.state in TOUCHING:
            out["fits"] = self.estimate.fits
        return out

    def brief(self) -> dict[str, Any]:
        return {k: v for k, v in self.status().items() if k in ("state", "result", "reason")}

    def health(self) -> Health:
        values = {k: v for k, v in self.status().items() if k != "dock"}
        if self.result == "failed" and not self.active:
            return Health("degraded", f"going home failed: {self.reason}", values)
        return Health("ok", values=values)

    # -- HTTP and topics -----------------------------------------------------------------------

    def routes(self) -> Sequence[Route]:
        return (Route("GET", "/api/dock", self.get_dock, "read"),
                Route("POST", "/api/dock", self.post_dock, "drive"),
                Route("POST", "/api/dock/go", self.post_go, "drive"),
                Route("POST", "/api/dock/leave", self.post_leave, "drive"))

    def topics(self) -> Sequence[Topic]:
        return (TopicOut("/dock/state", STRING, STATE, json_string_msg, "on change + 1 Hz"),
                TopicIn("/dock/command", STRING, self.on_command_message, "drive",
                        moves=True))

    async def get_dock(self, request: web.Request) -> web.Response:
        return json_response(self.status())

    async def post_dock(self, request: web.Request) -> web.Response:
        body = await read_json_object(request, 1024)
        frame = self.nav.frame if self.nav is not None else ""
        try:
            parsed = parse_pose(body, frame)
        except DockError as exc:
            raise ApiError(422, f"invalid dock: {exc}") from None
        try:
            if parsed is None:
                self.set_here()
            else:
                given, pose = parsed
                if self.nav is None:
                    raise DockError("setting the dock needs navigation: set [navigation] "
                                    "enabled")
                self.nav.to_frame(given, *pose)  # a frame navigation knows
                self.set_dock(given, pose)
        except ValueError as exc:
            raise ApiError(409, f"dock refused: {exc}") from None
        except OSError as exc:
            raise ApiError(500, f"cannot save the dock: {exc.strerror or exc}") from None
        self.publisher.publish(self.clock())
        return json_response(self.status())

    async def post_go(self, request: web.Request) -> web.Response:
        try:
            self.go_home()
        except DockError as exc:
            raise ApiError(409, f"going home refused: {exc}") from None
        return json_response(self.status())

    async def post_leave(self, request: web.Request) -> web.Response:
        try:
            self.leave()
        except DockError as exc:
            raise ApiError(409, f"leaving refused: {exc}") from None
        return json_response(self.status())

    async def on_command_message(self, message: Inbound) -> Refusal | None:
        """``/dock/command`` (std_msgs/String): ``go`` or ``leave``."""
        command = message.msg.get("data")
        try:
            if command == "go":
                self.go_home()
            elif command == "leave":
                self.leave()
            else:
                return Refusal(f"/dock/command: expected go or leave, got {command!r}")
        except DockError as exc:
            return Refusal(str(exc))
        return None

    async def stop(self) -> None:
        self.cancel("daemon stopping")


def create(ctx: DaemonContext) -> DockComponent | None:
    settings = ctx.settings(DockSettings)
    if not settings.enabled:
        return None
    from daemon.components.collision_monitor.settings import CollisionMonitorSettings
    nav, guard = ctx.components.get("navigation"), ctx.components.get("collision_monitor")
    battery, fetch = ctx.components.get("battery"), ctx.components.get("fetch")
    store = Path(settings.file).expanduser() if settings.file else \
        state_directory("dock") / "dock.json"
    component = DockComponent(
        settings, ctx.plugs, nav=nav if isinstance(nav, NavigationComponent) else None,
        guard=guard if hasattr(guard, "set_goal_zone") else None,  # type: ignore[arg-type]
        battery=battery if isinstance(battery, BatteryComponent) else None,
        fetch=fetch if isinstance(fetch, FetchComponent) else None, points=ctx.scan_points,
        footprint_radius=ctx.settings(CollisionMonitorSettings).footprint_radius, store=store)
    if isinstance(battery, BatteryComponent):
        battery.exempt = component.exempt
    return component


COMPONENT = ComponentSpec("dock", create, DockSettings)
