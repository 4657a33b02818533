# The "autonomy" component: the wander FSM as the lowest-priority command source, and its API.
from __future__ import annotations

import logging
import math
import random
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from aiohttp import web

from base.config import Config
from daemon.bus import BusKey
from daemon.commands import Twist
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, Plugs, Route
from daemon.components.autonomy.sectors import Sectors
from daemon.components.autonomy.settings import AutonomySettings
from daemon.components.autonomy.wander import Perception, Wander, WanderSettings
from daemon.components.collision_monitor.settings import CollisionMonitorSettings
from daemon.components.navigation.component import NavigationComponent
from daemon.health import Health
from daemon.messages.convert import json_string_msg
from daemon.messages.definitions import STRING
from daemon.robot import scan_points
from daemon.settings import LimitsSettings
from daemon.state_publisher import StatePublisher
from daemon.telemetry import SCAN
from daemon.topics import Inbound, Refusal, Topic, TopicIn, TopicOut
from daemon.web import ApiError, json_response, read_json_object
from sensors.rplidar.settings import LidarSettings
from sensors.scan import LaserScan, ScanPoints

log = logging.getLogger("arbiterd.autonomy")

SOURCE = "autonomy"
PRIORITY = 0  # below every client
MODES = ("off", "wander", "explore")
#: the behaviour's state, on change and once a second
STATE: BusKey[dict[str, Any]] = BusKey("autonomy_state")
PUBLISH_EVERY_S = 1.0
SECTORS = 48
#: the tight corridor is the footprint grown by the stop margin and this much (m)
TIGHT_EXTRA_M = 0.05
#: a scan older than this stops the behaviour (s)
SCAN_TIMEOUT_S = 0.5
#: after a stall stop the behaviour holds still until the control tick has run on time for
#: this long, then goes on by itself (s); an e-stop or a driver fault switches it off instead
RESUME_AFTER_STALL_S = 2.0
#: two ticks further apart than this many periods are no healthy tick
HEALTHY_GAP_PERIODS = 2.0


def wander_settings(config: Config) -> WanderSettings:
    a, limits = config.get(AutonomySettings), config.get(LimitsSettings)
    return WanderSettings(cruise_speed=min(a.cruise_speed, limits.linear_x_max_velocity),
                          turn_speed=min(a.turn_speed, limits.angular_z_max_velocity),
                          look_ahead=a.look_ahead_m)


class AutonomyComponent(BaseComponent):
    """Runs :class:`Wander` from the control tick when the mode is ``wander``.

    Its commands go through the arbiter (lowest priority) and so through the collision
    monitor and the limiter like any client's. A command from any other source switches the
    mode off at once; so do an e-stop or a driver fault once they clear (the robot waits to be
    asked again). A stall stop alone (the event loop was blocked) only holds it still: it goes
    on by itself once the tick has been healthy for ``RESUME_AFTER_STALL_S``. Reports in
    ``GET /api/autonomy`` and on the bus (``autonomy_state``, on change and once a second).
    """

    name = "autonomy"
    core = False

    def __init__(self, config: Config, plugs: Plugs, *, lidar: bool, seed: int | None = None,
                 points: ScanPoints | None = None,
                 components: Mapping[str, object] | None = None) -> None:
        #: the daemon's components by name, filled as they are built (navigation comes after
        #: this one in the table): the mode explore drives navigation's explorer
        self.components = components if components is not None else {}
        robot = self.robot = plugs.robot
        self.bus = plugs.bus
        self.lidar = lidar
        self.clock = robot.clock
        cm = config.get(CollisionMonitorSettings)
        radius = _footprint_reach(cm)
        autonomy = config.get(AutonomySettings)
        self.sectors = Sectors(SECTORS, radius + autonomy.clearance_m,
                               1.5 * autonomy.look_ahead_m,
                               tight_width=radius + cm.stop_margin_m + TIGHT_EXTRA_M)
        self.points = points or scan_points(config)
        seed = autonomy.seed if seed is None else seed
        self.wander = Wander(wander_settings(config), random.Random(seed or None))
        self.period = 1.0 / autonomy.decision_rate
        self.mode = "off"
        self.free: np.ndarray | None = None
        self._scan: LaserScan | None = None
        self.scan_time: float | None = None
        self._next_decision = -math.inf
        self._invalidations = robot.invalidations
        self._stall_invalidations = robot.stall_invalidations
        self._latched = False
        #: after a stall stop: when the tick has been healthy long enough to move again
        self._resume_at: float | None = None
        self._last_tick: float | None = None
        self._published_state = ""
        self.hooks = plugs.while_busy(tick_source=self._tick, on_command=self._on_command)
        self.publisher = StatePublisher(plugs, STATE, self.status, PUBLISH_EVERY_S)
        plugs.subscribe(SCAN, self.on_scan)
        self._initial_mode = autonomy.mode

    # -- mode ----------------------------------------------------------------------------------

    def refusal(self, mode: str) -> str | None:
        """Why ``mode`` cannot start now, or None."""
        if mode == "off":
            return None
        if not self.lidar:
            return f"{mode} needs the lidar: enable [lidar]"
        if mode == "explore" and self._navigation() is None:
            return "explore needs the navigation component: enable [navigation]"
        if self.robot.estop_engaged:
            return "e-stop engaged: release it first"
        if self.robot.fault:
            return f"driver fault: {self.robot.fault}"
        return None

    def set_mode(self, mode: str, reason: str) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        now = self.clock()
        if mode == self.mode:
            return
        previous, self.mode = self.mode, mode
        if mode == "wander":
            self._invalidations = self.robot.invalidations
            self._stall_invalidations = self.robot.stall_invalidations
            self._latched = False
            self._resume_at = None
            self._next_decision = now
            self.wander.start(now, self.robot.heading())
        else:
            self.wander.stop(now, reason)
            self.robot.withdraw(SOURCE)
        navigation = self._navigation()
        if previous == "explore" and navigation is not None:
            navigation.stop_exploring(reason)
        if mode == "explore":
            refusal = "no navigation component" if navigation is None else \
                navigation.start_exploring(reason)
            if refusal:
                log.error("autonomy explore refused: %s", refusal)
                self.mode = "off"
        if self.mode == "off":
            self.hooks.stop()
        else:
            self._last_tick = None
            self.hooks.start()
        log.info("autonomy %s (%s)", self.mode, reason)
        self.publisher.publish(now)

    def _navigation(self) -> NavigationComponent | None:
        """The navigation component, which explores for the mode ``explore``."""
        navigation = self.components.get("navigation")
        return navigation if isinstance(navigation, NavigationComponent) else None

    def request(self, mode: str, reason: str = "requested") -> str | None:
        """Switch the mode if it may be switched now; why not, else None."""
        if mode not in MODES:
            return f"mode must be one of {', '.join(MODES)}, got {mode!r}"
        refusal = self.refusal(mode)
        if refusal is None:
            self.set_mode(mode, reason)
        return refusal

    async def on_mode_message(self, message: Inbound) -> Refusal | None:
        """``/autonomy/mode`` (std_msgs/String): ``wander``, ``explore`` or ``off``."""
        refusal = self.request(str(message.msg["data"]), message.sender)
        return None if refusal is None else Refusal(refusal)

    def _on_command(self, source: str) -> None:
        if source != SOURCE and self.mode != "off":
            self.set_mode("off", f"teleop from {source}")

    # -- inputs --------------------------------------------------------------------------------

    def on_scan(self, scan: LaserScan) -> None:
        """Keep the revolution; its histogram is built when a decision needs it."""
        self._scan = scan
        self.scan_time = self.clock()

    def _histogram(self) -> np.ndarray | None:
        if self._scan is not None:
            self.free = self.sectors.free(*self.points(self._scan))
            self._scan = None
        return self.free

    def _blocked(self, now: float) -> str | None:
        robot = self.robot
        if robot.invalidations != self._invalidations:
            stalls = robot.stall_invalidations - self._stall_invalidations
            if robot.invalidations - self._invalidations > stalls:
                self._latched = True  # an e-stop, a fault, a reconnect: ask again to resume
            else:
                self._resume_at = now + RESUME_AFTER_STALL_S  # only stalls: wait, go on
            self._invalidations = robot.invalidations
            self._stall_invalidations = robot.stall_invalidations
        if robot.estop_engaged:
            return "e-stop engaged"
        if robot.fault:
            return f"driver fault: {robot.fault}"
        if self.scan_time is None or now - self.scan_time > SCAN_TIMEOUT_S:
            return "no fresh lidar scan"
        if self._resume_at is not None:
            if now < self._resume_at:
                return "stall stop: waiting for the control tick to stay on time"
            self._resume_at = None
        return None

    # -- the tick ------------------------------------------------------------------------------

    def _tick(self, now: float) -> None:
        last, self._last_tick = self._last_tick, now
        if self._resume_at is not None and last is not None \
                and now - last > HEALTHY_GAP_PERIODS * self.robot.period_s:
            self._resume_at = now + RESUME_AFTER_STALL_S  # a late tick: the wait starts over
        if self.mode == "explore":
            self._watch_exploration()
            return
        if self.mode == "off" or now < self._next_decision:
            return
        self._next_decision = now + self.period - 1e-9
        blocked = self._blocked(now)
        if blocked is None and self._latched:
            self.set_mode("off", "e-stop, fault or stall cleared: ask again to resume")
            return
        histogram = self._histogram()
        free = histogram if histogram is not None else np.zeros((2, self.sectors.count))
        seen = Perception(free[0], self.sectors.angles, self.robot.heading(), blocked,
                          self._held(), free[1])
        previous = self.wander.state
        v, w = self.wander.decide(now, seen)
        self.robot.propose(SOURCE, Twist(v, w), now, PRIORITY)
        if self.wander.state != previous:
            log.debug("wander %s -> %s (%s)", previous, self.wander.state, self.wander.reason)
            self.publisher.publish(now)

    def _watch_exploration(self) -> None:
        """The navigation component drives while exploring; the mode ends with it."""
        navigation = self._navigation()
        if navigation is None or not navigation.exploring:
            explorer = navigation.explorer if navigation is not None else None
            why = "no navigation component" if explorer is None else \
                f"exploration {explorer.state}" + (f": {explorer.reason}"
                                                   if explorer.reason else "")
            self.set_mode("off", why)

    def _held(self) -> bool:
        return self.robot.safety_action() == "stop"

    def status(self) -> dict[str, Any]:
        now = self.clock()
        wander = self.wander
        times = wander.times(now)
        out = {"mode": self.mode, "state": wander.state,
               "time_in_state_s": round(max(0.0, now - wander.since), 3),
               "transitions": wander.transitions, "reason": wander.reason,
               "state_times_s": {k: round(v, 3) for k, v in times.items()}}
        navigation = self._navigation()
        if navigation is not None and navigation.explorer.state != "idle":
            out["exploration"] = navigation.exploration()
        return out

    # -- HTTP ----------------------------------------------------------------------------------

    async def get_autonomy(self, request: web.Request) -> web.Response:
        return json_response(self.status())

    async def post_autonomy(self, request: web.Request) -> web.Response:
        body = await read_json_object(request, 4096)
        unknown = sorted(set(body) - {"mode"})
        if unknown:
            raise ApiError(422, f"invalid autonomy request: {unknown[0]}: unknown field")
        mode = body.get("mode")
        if mode not in MODES:
            raise ApiError(422, "invalid autonomy request: mode: expected \"wander\", "
                           "\"explore\" or \"off\"", {"got": mode})
        refusal = self.request(mode, "requested over HTTP")
        if refusal:
            raise ApiError(409, f"autonomy refused: {refusal}")
        return json_response(self.status())

    # -- component -----------------------------------------------------------------------------

    def routes(self) -> Sequence[Route]:
        return (Route("GET", "/api/autonomy", self.get_autonomy, "read"),
                Route("POST", "/api/autonomy", self.post_autonomy, "drive"))

    def topics(self) -> Sequence[Topic]:
        return (TopicIn("/autonomy/mode", STRING, self.on_mode_message, "drive", moves=True),
                TopicOut("/autonomy/state", STRING, STATE, json_string_msg,
                         "on change + 1 Hz"))

    async def start(self) -> None:
        if self._initial_mode != "off":
            refusal = self.refusal(self._initial_mode)
            if refusal:
                log.error("[autonomy] mode = %s: %s", self._initial_mode, refusal)
            else:
                self.set_mode(self._initial_mode, "[autonomy] mode")

    async def stop(self) -> None:
        if self.mode != "off":
            self.set_mode("off", "daemon stopping")

    def health(self) -> Health:
        return Health("ok", values=self.status())


def _footprint_reach(cm: CollisionMonitorSettings) -> float:
    if cm.footprint:
        return max(math.hypot(x, y) for x, y in cm.footprint)
    return float(cm.footprint_radius)


def create(ctx: DaemonContext) -> AutonomyComponent:
    """The autonomy component (always present; ``mode`` off until asked)."""
    return AutonomyComponent(ctx.config, ctx.plugs, lidar=ctx.settings(LidarSettings).enabled,
                             points=ctx.scan_points, components=ctx.components)


COMPONENT = ComponentSpec("autonomy", create, AutonomySettings)
