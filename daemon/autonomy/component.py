# The "autonomy" component: the wander FSM as the lowest-priority command source, and its API.
from __future__ import annotations

import logging
import math
import random
from typing import Any

import numpy as np
from aiohttp import web

from daemon.autonomy.sectors import Sectors
from daemon.autonomy.wander import Perception, Wander, WanderSettings
from daemon.bus import Bus
from daemon.config import Config
from daemon.control.commands import Twist
from daemon.control.loop import ControlLoop
from daemon.http_api import ApiError, json_response, read_json_object
from daemon.safety.component import ScanPoints, StatePublisher, scan_points, shared_points
from sensors.scan import LaserScan

log = logging.getLogger("arbiterd.autonomy")

SOURCE = "autonomy"
PRIORITY = 0  # below every client
MODES = ("off", "wander")
STATE_TOPIC = "autonomy_state"
PUBLISH_EVERY_S = 1.0
SECTORS = 48
#: the tight corridor is the footprint grown by the stop margin and this much (m)
TIGHT_EXTRA_M = 0.05
#: a scan older than this stops the behaviour (s)
SCAN_TIMEOUT_S = 0.5


def wander_settings(config: Config) -> WanderSettings:
    a = config["autonomy"]
    return WanderSettings(cruise_speed=min(a["cruise_speed"],
                                           config["limits"]["linear.x.max_velocity"]),
                          turn_speed=min(a["turn_speed"],
                                         config["limits"]["angular.z.max_velocity"]),
                          look_ahead=a["look_ahead_m"])


class AutonomyComponent:
    """Runs :class:`Wander` from the control tick when the mode is ``wander``.

    Its commands go through the arbiter (lowest priority) and so through the collision
    monitor and the limiter like any client's. A command from any other source switches the
    mode off at once; so do an e-stop, a driver fault or a stall once they clear (the robot
    waits to be asked again). Reports in ``GET /api/autonomy`` and on the bus
    (``autonomy_state``, on change and once a second).
    """

    name = "autonomy"
    core = False

    def __init__(self, config: Config, control: ControlLoop, bus: Bus,
                 *, lidar: bool, seed: int | None = None,
                 points: ScanPoints | None = None) -> None:
        self.control = control
        self.bus = bus
        self.lidar = lidar
        self.clock = control.clock
        cm = config["collision_monitor"]
        radius = _footprint_reach(cm)
        autonomy = config["autonomy"]
        self.sectors = Sectors(SECTORS, radius + autonomy["clearance_m"],
                               1.5 * autonomy["look_ahead_m"],
                               tight_width=radius + cm["stop_margin_m"] + TIGHT_EXTRA_M)
        self.points = points or scan_points(config)
        seed = autonomy["seed"] if seed is None else seed
        self.wander = Wander(wander_settings(config), random.Random(seed or None))
        self.period = 1.0 / autonomy["decision_rate"]
        self.mode = "off"
        self.free: np.ndarray | None = None
        self._scan: LaserScan | None = None
        self.scan_time: float | None = None
        self._next_decision = -math.inf
        self._invalidations = control.invalidations
        self._latched = False
        self._published_state = ""
        control.behaviours[SOURCE] = self.request
        control.tick_sources.append(self._tick)
        control.on_command.append(self._on_command)
        self.publisher = StatePublisher(bus, STATE_TOPIC, self.status, control, PUBLISH_EVERY_S)
        bus.subscribe("scan", self.on_scan)
        self._initial_mode = autonomy["mode"]

    # -- mode ----------------------------------------------------------------------------------

    def refusal(self, mode: str) -> str | None:
        """Why ``mode`` cannot start now, or None."""
        if mode == "off":
            return None
        if not self.lidar:
            return "wander needs the lidar: enable [lidar]"
        if self.control.arbiter.estop_engaged:
            return "e-stop engaged: release it first"
        if self.control.fault:
            return f"driver fault: {self.control.fault}"
        return None

    def set_mode(self, mode: str, reason: str) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        now = self.clock()
        if mode == self.mode:
            return
        self.mode = mode
        if mode == "wander":
            self._invalidations = self.control.invalidations
            self._latched = False
            self._next_decision = now
            self.wander.start(now, self.control.odometry.theta)
        else:
            self.wander.stop(now, reason)
            self.control.arbiter.drop(SOURCE)
        log.info("autonomy %s (%s)", mode, reason)
        self.publisher.publish(now)

    def request(self, mode: str, reason: str = "requested") -> str | None:
        """Switch the mode if it may be switched now; why not, else None."""
        if mode not in MODES:
            return f"mode must be one of {', '.join(MODES)}, got {mode!r}"
        refusal = self.refusal(mode)
        if refusal is None:
            self.set_mode(mode, reason)
        return refusal

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
        control = self.control
        if control.invalidations != self._invalidations:
            self._invalidations = control.invalidations
            self._latched = True
        if control.arbiter.estop_engaged:
            return "e-stop engaged"
        if control.fault:
            return f"driver fault: {control.fault}"
        if self.scan_time is None or now - self.scan_time > SCAN_TIMEOUT_S:
            return "no fresh lidar scan"
        return None

    # -- the tick ------------------------------------------------------------------------------

    def _tick(self, now: float) -> None:
        if self.mode == "off" or now < self._next_decision:
            return
        self._next_decision = now + self.period - 1e-9
        blocked = self._blocked(now)
        if blocked is None and self._latched:
            self.set_mode("off", "e-stop, fault or stall cleared: ask again to resume")
            return
        histogram = self._histogram()
        free = histogram if histogram is not None else np.zeros((2, self.sectors.count))
        seen = Perception(free[0], self.sectors.angles, self.control.odometry.theta, blocked,
                          self._held(), free[1])
        previous = self.wander.state
        v, w = self.wander.decide(now, seen)
        self.control.arbiter.submit(SOURCE, Twist(v, w), now, PRIORITY)
        if self.wander.state != previous:
            log.debug("wander %s -> %s (%s)", previous, self.wander.state, self.wander.reason)
            self.publisher.publish(now)

    def _held(self) -> bool:
        guard = self.control.guard
        action = getattr(guard, "action", "none")
        return action == "stop"

    def status(self) -> dict[str, Any]:
        now = self.clock()
        wander = self.wander
        times = wander.times(now)
        return {"mode": self.mode, "state": wander.state,
                "time_in_state_s": round(max(0.0, now - wander.since), 3),
                "transitions": wander.transitions, "reason": wander.reason,
                "state_times_s": {k: round(v, 3) for k, v in times.items()}}

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
            raise ApiError(422, "invalid autonomy request: mode: expected \"wander\" or "
                           "\"off\"", {"got": mode})
        refusal = self.request(mode, "requested over HTTP")
        if refusal:
            raise ApiError(409, f"autonomy refused: {refusal}")
        return json_response(self.status())

    # -- component -----------------------------------------------------------------------------

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

    def health(self) -> dict[str, Any]:
        return {"status": "ok", **self.status()}


def _footprint_reach(cm: dict[str, Any]) -> float:
    if cm["footprint"]:
        return max(math.hypot(x, y) for x, y in cm["footprint"])
    return float(cm["footprint_radius"])


def create(ctx: Any) -> AutonomyComponent:
    """The autonomy component (always present; ``mode`` off until asked)."""
    component = AutonomyComponent(ctx.config, ctx.control, ctx.bus,
                                  lidar=ctx.config["lidar"]["enabled"],
                                  points=shared_points(ctx))
    ctx.http.add_route("GET", "/api/autonomy", component.get_autonomy, access="read")
    ctx.http.add_route("POST", "/api/autonomy", component.post_autonomy, access="drive")
    return component
