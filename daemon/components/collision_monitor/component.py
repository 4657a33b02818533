# The "collision_monitor" component: scans in, a guard on every control step, its state out.
from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from typing import Any

from prometheus_client import CollectorRegistry, Counter

from base.config import Config
from daemon.bus import BusKey
from daemon.clock import Clock
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, Plugs
from daemon.components.collision_monitor.braking import BrakingCheck
from daemon.components.collision_monitor.footprint import Footprint
from daemon.components.collision_monitor.monitor import ACTIONS, CollisionMonitor, MonitorSettings
from daemon.components.collision_monitor.settings import CollisionMonitorSettings
from daemon.components.collision_monitor.sweep import path_direction
from daemon.health import Health
from daemon.messages.convert import json_string_msg
from daemon.messages.definitions import STRING
from daemon.motion_guard import Guarded
from daemon.robot import scan_points
from daemon.settings import ControlSettings, LimitsSettings
from daemon.state_publisher import StatePublisher
from daemon.telemetry import SCAN
from daemon.topics import Topic, TopicOut
from sensors.rplidar.settings import LidarSettings
from sensors.scan import LaserScan, ScanPoints

log = logging.getLogger("arbiterd.safety")

#: a less severe action is reported only after the more severe one is this long gone (s)
HOLD_S = 0.25
#: the monitor's state, on change and once a second
STATE: BusKey[dict[str, Any]] = BusKey("collision_monitor_state")
SEVERE_FIRST = ACTIONS[:0:-1]  # stop, limit, slowdown


def monitor_settings(config: Config) -> MonitorSettings:
    """The monitor's settings from ``[collision_monitor]``, ``[limits]`` and ``[control]``."""
    cm, limits = config.get(CollisionMonitorSettings), config.get(LimitsSettings)
    footprint = (Footprint.from_points(cm.footprint) if cm.footprint
                 else Footprint.circle(cm.footprint_radius))
    return MonitorSettings(
        footprint=footprint, stop_margin=cm.stop_margin_m,
        slowdown_margin=max(cm.slowdown_margin_m, cm.stop_margin_m),
        slowdown_ratio=cm.slowdown_ratio,
        time_before_collision=cm.time_before_collision_s,
        reaction_time=cm.reaction_time_s + unattended_s(config.get(ControlSettings)),
        motor_lag=cm.reaction_time_s,
        min_points=cm.min_points, source_timeout=cm.source_timeout_s,
        stale_action=cm.stale_action,
        linear_deceleration=limits.linear_x_emergency_deceleration,
        angular_deceleration=limits.angular_z_emergency_deceleration,
        max_linear=limits.linear_x_max_velocity, max_angular=limits.angular_z_max_velocity)


def unattended_s(control: ControlSettings) -> float:
    """How long the wheels may keep their last command with nobody to change it: until the
    stall supervisor zeroes them when the event loop stops (``stall_stop_s``, at least two
    control periods, as the loop enforces), else one control period."""
    period = 1.0 / control.update_rate
    return max(2.0 * period, control.stall_stop_s) if control.stall_stop_s > 0 else period


def horizon_warning(settings: MonitorSettings) -> str | None:
    """A warning when the approach check cannot see far enough to stop from full speed."""
    v, a = settings.max_linear, settings.linear_deceleration
    needed = settings.reaction_time + v / (2.0 * a)
    if settings.time_before_collision >= needed:
        return None
    return (f"[collision_monitor] time_before_collision_s = {settings.time_before_collision:g} "
            f"is shorter than the {needed:.2f} s the robot needs to stop from "
            f"{v:g} m/s: obstacles may be seen too late; raise it")


class SafetyMetrics:
    """Prometheus counters of the monitor's interventions."""

    def __init__(self, registry: CollectorRegistry) -> None:
        self.changes = Counter("arbiterd_collision_monitor_actions", "times the collision "
                               "monitor's action changed to this one", ["action"],
                               registry=registry)
        self.steps = Counter("arbiterd_collision_monitor_interventions", "control steps in "
                             "which the collision monitor changed the target", ["action"],
                             registry=registry)
        self.changes_by_action = {a: self.changes.labels(a) for a in ACTIONS}
        self.steps_by_action = {a: self.steps.labels(a) for a in ACTIONS if a != "none"}


class SafetyComponent(BaseComponent):
    """The collision monitor in the daemon: the control loop's guard (component
    ``collision_monitor``, non-core). Reports ``safety`` in ``/api/status``, logs every change
    of action, counts, and publishes its state on ``/collision_monitor/state``."""

    name = "collision_monitor"
    core = False

    def __init__(self, config: Config, plugs: Plugs, registry: CollectorRegistry, *,
                 wall_clock: Clock = time.time, points: ScanPoints | None = None) -> None:
        robot, bus = plugs.robot, plugs.bus
        self.settings = monitor_settings(config)
        self.monitor = CollisionMonitor(self.settings)
        self.braking = BrakingCheck(self.settings.motor_lag)
        self.points = points or scan_points(config)
        self.clock = robot.clock
        self.wall_clock = wall_clock
        self.bus = bus
        self.robot = robot
        self.metrics = SafetyMetrics(registry)
        self.action = "stop"  # until the first revolution arrives (not logged as a change)
        self.reason = "no lidar revolution yet"
        self.changes = 0
        self.time_in: dict[str, float] = dict.fromkeys(ACTIONS, 0.0)
        self.entries: dict[str, int] = dict.fromkeys(ACTIONS, 0)
        self._seen: dict[str, float] = dict.fromkeys(ACTIONS, -math.inf)
        self._last_target = (0.0, 0.0)
        self._last_report = -math.inf
        plugs.add(robot.set_guard(self))
        plugs.add_status("safety", self.status)
        self.publisher = StatePublisher(plugs, STATE, self.status)
        plugs.subscribe(SCAN, self.on_scan)

    # -- the guard -----------------------------------------------------------------------------

    def limit(self, linear: float, angular: float, current_linear: float,
              current_angular: float, now: float) -> Guarded:
        verdict = self.monitor.limit(linear, angular, current_linear, current_angular, now)
        self._last_target = (linear, angular)
        if verdict.action != "none":
            self.metrics.steps_by_action[verdict.action].inc()
        self._report(verdict.action, verdict.reason, now)
        return Guarded(verdict.linear, verdict.angular, verdict.brake, verdict.action)

    def observe(self, now: float, x: float, y: float, theta: float) -> None:
        self.monitor.observe(now, x, y, theta)
        if self.robot.measured_wheel_speeds() is not None:  # only what encoders measured
            commanded = path_direction(*self.robot.limited_velocity())[1]
            self.braking.observe(now, commanded, (x, y, theta))

    def on_scan(self, scan: LaserScan) -> None:
        """A revolution from the bus; its stamp (wall clock of the first ray) is turned into
        control-clock time."""
        now = self.clock()
        age = min(max(0.0, self.wall_clock() - scan.stamp), 60.0)
        px, py = self.points(scan)
        t_first = now - age
        self.monitor.on_scan(px, py, t_first, t_first + max(0.0, scan.scan_time))
        self.monitor.warm(self._last_target, self.robot.limited_velocity())

    def set_goal_zone(self, segments: list[tuple[float, float, float, float]] | None,
                      band: float = 0.0) -> None:
        """What the robot is meant to touch now (a dock's arms, in the odometry frame): the
        lidar points within ``band`` of it are no obstacle until ``None`` clears it; every
        other point keeps its margins."""
        if (segments is None) != (self.monitor.goal_zone is None):
            log.info("collision monitor: %s", "the dock is the goal: its arms are no obstacle"
                     if segments else "no goal zone")
        self.monitor.set_goal_zone(segments, band)

    # -- reporting -----------------------------------------------------------------------------

    def _report(self, action: str, reason: str, now: float) -> None:
        """The reported action is the most severe one seen within ``HOLD_S``."""
        seen = self._seen
        seen[action] = now
        held = next((a for a in SEVERE_FIRST if now - seen[a] <= HOLD_S), "none")
        elapsed = now - self._last_report if self._last_report > -math.inf else 0.0
        self.time_in[self.action] += max(0.0, elapsed)
        self._last_report = now
        if held == action:
            self.reason = reason
        if held != self.action:
            self._change(held, now)

    def _change(self, action: str, now: float) -> None:
        previous, self.action = self.action, action
        self.changes += 1
        self.entries[action] += 1
        self.metrics.changes_by_action[action].inc()
        level = logging.WARNING if action == "stop" else logging.INFO
        nearest = self.monitor.nearest()
        log.log(level, "collision monitor: %s -> %s (%s; nearest obstacle %s)", previous,
                action, self.reason or "clear", f"{nearest:.2f} m" if nearest is not None
                else "unknown")
        self.publisher.publish(now)

    def status(self) -> dict[str, Any]:
        now = self.clock()
        age = self.monitor.scan_age(now)
        nearest = self.monitor.nearest()
        return {"enabled": True, "action": self.action, "zone": self.monitor.zone(now),
                "nearest_m": None if nearest is None else round(nearest, 3),
                "scan_age_s": None if age is None else round(age, 3), "reason": self.reason,
                "goal_zone": self.monitor.goal_zone is not None}

    # -- component -----------------------------------------------------------------------------

    def topics(self) -> Sequence[Topic]:
        return (state_topic(),)

    def health(self) -> Health:
        now = self.clock()
        stale = self.monitor.stale(now)
        slow_brakes = self.braking.reason()
        values = {**self.status(), "stale": stale, "scans": self.monitor.scans,
                  "changes": self.changes, "entries": dict(self.entries),
                  "braking": self.braking.health(self.robot.measured_wheel_speeds() is not None)}
        if stale:
            return Health("degraded", f"no fresh lidar scan: {self.reason}", values)
        if slow_brakes:
            return Health("degraded", slow_brakes, values)
        return Health("ok", values=values)


def disabled_status() -> dict[str, Any]:
    return {"enabled": False, "action": "none", "zone": "unknown", "nearest_m": None,
            "scan_age_s": None, "reason": "collision monitor disabled"}


def state_topic() -> TopicOut[dict[str, Any]]:
    return TopicOut("/collision_monitor/state", STRING, STATE, json_string_msg,
                    "on change + 1 Hz")


def create(ctx: DaemonContext) -> SafetyComponent | None:
    """Build the monitor when ``[lidar]`` and ``[collision_monitor]`` are enabled."""
    config = ctx.config
    if not config.get(LidarSettings).enabled:
        ctx.plugs.add_status("safety", lambda: {
            **disabled_status(), "reason": "no lidar: nothing keeps the robot out of obstacles"})
        return None
    if not config.get(CollisionMonitorSettings).enabled:
        log.warning("[collision_monitor] enabled = false: the lidar does NOT keep the robot "
                    "out of obstacles")
        ctx.plugs.add_status("safety", disabled_status)
        return None
    component = SafetyComponent(config, ctx.plugs, ctx.latency.metrics.registry,
                                points=ctx.scan_points)
    warning = horizon_warning(component.settings)
    if warning:
        log.warning("%s", warning)
    return component


COMPONENT = ComponentSpec("collision_monitor", create, CollisionMonitorSettings)
