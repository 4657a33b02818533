# The lockstep runner: control loop, collision monitor, autonomy and world on one virtual clock.
from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from base.config import Config
from daemon.bus import Bus
from daemon.clock import VirtualClock
from daemon.commands import Twist
from daemon.component import Plugs
from daemon.components.arm.component import tool_at
from daemon.components.arm.controller import ArmController
from daemon.components.arm.settings import ArmSettings
from daemon.components.autonomy.component import AutonomyComponent
from daemon.components.battery.component import BatteryComponent
from daemon.components.battery.settings import BatterySettings
from daemon.components.collision_monitor.component import SafetyComponent
from daemon.components.collision_monitor.settings import CollisionMonitorSettings
from daemon.components.control.loop import ControlLoop
from daemon.components.dock.component import DockComponent
from daemon.components.dock.settings import DockSettings
from daemon.components.fetch.component import FetchComponent
from daemon.components.fetch.settings import FetchSettings
from daemon.components.navigation.component import NavigationComponent
from daemon.config import wheel_speed_clamp
from daemon.latency import LatencyTracker
from daemon.lockstep.driver import WorldDriver
from daemon.lockstep.mapping import MappingProbe
from daemon.lockstep.script import Step
from daemon.robot import scan_points
from daemon.settings import RobotSettings
from daemon.telemetry import SCAN
from drivers.devices import create_device
from drivers.servo_array import ServoArray
from sensors.scan import LaserScan, ScanPoints
from sim.coverage import Coverage
from sim.settings import SimConfig, SimSettings
from sim.stepper import SimWorld

SCRIPT_SOURCE = "script"


@dataclass
class Sender:
    """A scripted teleop client: re-sends its twist at a fixed rate."""

    twist: Twist | None = None
    period: float = 0.1
    next_send: float = math.inf
    sent: int = 0
    refused: int = 0


@dataclass
class LidarFeed:
    """The simulated lidar in lockstep: a revolution is cast at its first ray's time and
    delivered one revolution later (as the device delivers it), unless stalled."""

    period: float
    next_cast: float = 0.0
    pending: list[tuple[float, LaserScan]] = field(default_factory=list)
    stalled: bool = False
    delivered: int = 0


class Lockstep:
    """Builds the daemon's control code around a :class:`SimWorld` and steps both.

    Per physics step at virtual time t: due script steps, due lidar revolutions (published on
    the bus as the lidar component does), a control tick when one is due (internal sources,
    arbiter, collision monitor, limiter, the driver write into the world's motors, odometry
    from the world's encoders), then the world's physics step. Nothing sleeps; the clock only
    moves here, so a run repeats exactly for a seed.
    """

    def __init__(self, config: Config, *, script: Sequence[Step] = (),
                 autonomy: str | None = None, mapping: bool = False,
                 map_out: str | None = None, navigation: bool = False,
                 fetch: bool = False, dock: bool = False) -> None:
        self.config = config
        self._simulated_lidar(config)
        self.clock = VirtualClock()
        sim = SimConfig.from_settings(config.get(SimSettings))
        robot = config.get(RobotSettings)
        self.world = SimWorld(sim, wheel_radius=robot.wheel_radius,
                              wheel_separation=robot.wheel_separation)
        self.bus = Bus()
        self.latency = LatencyTracker(window=1000)
        max_wheel = wheel_speed_clamp(config)
        self.driver = WorldDriver(self.world.motors, self.clock, max_wheel_speed=max_wheel)
        self.control = ControlLoop(config, self.driver, self.bus, self.latency, clock=self.clock)
        points = scan_points(config)
        self.plugs = Plugs(self.control, self.control, self.bus)
        self.safety = (SafetyComponent(config, self.plugs, self.latency.metrics.registry,
                                       wall_clock=self.clock, points=points)
                       if config.get(CollisionMonitorSettings).enabled else None)
        self.components: dict[str, object] = {}  # what the autonomy's mode explore drives
        self.autonomy = AutonomyComponent(config, self.plugs, lidar=True, seed=sim.seed,
                                          points=points, components=self.components)
        self.script = list(script)
        self.start_mode = autonomy
        self.sender = Sender()
        self.lidar = LidarFeed(1.0 / sim.lidar_rate)
        #: the event loop is blocked until this time (script ``stall``)
        self.stalled_until = -math.inf
        #: when the collision monitor first had to brake (a limit or a stop)
        self.first_brake: float | None = None
        self.control.supervisor.clock = self.clock
        self.coverage = Coverage(self.world.world, sim.footprint_radius)
        self.marks: list[dict[str, Any]] = []
        self.min_clearance = math.inf
        self._clearance_bound = -math.inf
        self._since_clearance = 0.0
        self.truth_at_cast: dict[float, tuple[float, float, float]] = {}
        self.map_out = map_out
        self._step_index, self._next_tick = 0, 0.0
        self.control.supervisor.beat()
        self.mapping = MappingProbe(config, self.plugs, points, self.clock, self.world.world,
                                    self.truth_at_cast) if mapping else None
        self.navigation = NavigationComponent(config, self.plugs, lidar=True, points=points,
                                              inline=True, wall_clock=self.clock) \
            if navigation or fetch or dock else None
        if self.navigation is not None:
            self.components["navigation"] = self.navigation
        self.arm: ArmController | None = None
        self.fetch: FetchComponent | None = None
        if fetch:
            self._build_fetch(config)
        self.battery: BatteryComponent | None = None
        self.dock: DockComponent | None = None
        if dock:
            self._build_dock(config, points)

    def _build_dock(self, config: Config, points: ScanPoints) -> None:
        """The battery (reading the world's pack) with its policy, and the dock over
        navigation, the collision monitor and the fetch."""
        config.update("battery", {"enabled": True, "device": "sim"})
        battery = BatteryComponent(config.get(BatterySettings), self.plugs,
                                   model=self.world.battery.measure, wall_clock=self.clock)
        self.battery = battery
        nav = self.navigation
        assert nav is not None
        nav.gates.append(battery.refusal)
        self.dock = DockComponent(
            config.get(DockSettings), self.plugs, nav=nav, guard=self.safety,
            battery=battery, fetch=self.fetch, points=points,
            footprint_radius=config.get(CollisionMonitorSettings).footprint_radius,
            store=None, wall_clock=self.clock)
        battery.exempt = self.dock.exempt

    def _build_fetch(self, config: Config) -> None:
        """The arm (mock servos, stepped in each tick) and the fetch behaviour over it and
        navigation; the world's objects follow the arm's tool point."""
        config.update("arm", {"enabled": True, "backend": "mock"})
        settings = config.get(ArmSettings)
        servo = create_device(settings.device, config["arm"], section="arm")
        assert isinstance(servo, ServoArray)
        arbiter = self.control.arbiter
        arm = ArmController(settings, servo, self.clock(),
                            lambda: (arbiter.estop_reason or "latched")
                            if arbiter.estop_engaged else None)
        self.arm = arm
        objects = self.world.objects
        self.world.arm_tool = lambda: tool_at(
            arm.joints, arm.written or arm.motion.position(self.clock()))
        self.fetch = FetchComponent(config.get(FetchSettings), self.plugs,
                                    nav=self.navigation, arm=arm,
                                    held=lambda: objects.held is not None,
                                    miss=objects.miss)

    @staticmethod
    def _simulated_lidar(config: Config) -> None:
        """The world's lidar sits at the robot's centre and is always there."""
        sim = config.get(SimSettings)
        config.update("lidar", {"enabled": True, "mount_x": 0.0, "mount_y": 0.0,
                                "mount_yaw_deg": 0.0, "range_min": sim.range_min,
                                "range_max": sim.range_max})

    # -- running --------------------------------------------------------------------------------

    async def run(self, seconds: float) -> dict[str, Any]:
        start = time.perf_counter()
        await self.begin()
        await self.advance(seconds)
        await self._script_until(self.now, final=True)
        result = self.report(seconds, time.perf_counter() - start)
        await self.finish()
        return result

    async def begin(self) -> None:
        """Start the control loop (and the mapper, and the --autonomy mode) at time 0."""
        await self.control.start(realtime=False)
        if self.arm is not None:
            await self.arm.servo.open()
            await self.arm.step(self.clock())
        if self.mapping is not None:
            await self.mapping.start()
        if self.start_mode:
            self.autonomy.set_mode(self.start_mode, "--autonomy")
        self._step_index, self._next_tick = 0, 0.0

    @property
    def now(self) -> float:
        return self._step_index * self.world.config.physics_dt

    async def advance(self, seconds: float, until: Callable[[], bool] | None = None) -> None:
        """Step the world and the daemon's code ``seconds`` on (or until ``until()`` holds,
        checked after each control tick)."""
        dt = self.world.config.physics_dt
        period = self.control.period_s
        end = self._step_index + round(seconds / dt)
        while self._step_index < end:
            t = self._step_index * dt
            self.clock.set(t)
            await self._script_until(t)
            self._lidar_at(t)
            ticked = t + 1e-9 >= self._next_tick
            if ticked:
                if t + 1e-9 >= self.stalled_until:  # a scripted stall: the loop is blocked
                    await self._tick(self._next_tick)
                self._next_tick += period
            if self.control.supervisor.enabled:
                self.control.supervisor.check()  # the supervisor's thread, in virtual time
            self.world.step()
            self._track()
            self._step_index += 1
            if ticked and until is not None and until():
                break
        self.clock.set(self.now)

    async def finish(self) -> None:
        await self.control.stop()
        self.world.close()

    async def _tick(self, deadline: float) -> None:
        self.control.supervisor.beat()
        moving = self.control.linear.velocity != 0.0 or self.control.angular.velocity != 0.0
        await self.control.tick(deadline)
        if self.arm is not None:
            await self.arm.step(deadline)
        if self.first_brake is None and moving and \
                self.control.guard_action in ("limit", "stop"):
            self.first_brake = deadline

    async def _script_until(self, t: float, final: bool = False) -> None:
        while self.script and self.script[0].t <= t + 1e-9:
            step = self.script.pop(0)
            self._mark(step.label, t)
            await self._apply(step, t)
        if final or t + 1e-9 < self.stalled_until:
            return  # a blocked loop reads no commands (the client re-sends later)
        sender = self.sender
        if sender.twist is not None and t + 1e-9 >= sender.next_send:
            applied = await self.control.submit(SCRIPT_SOURCE, sender.twist, t_recv=t)
            sender.sent += 1
            sender.refused += not applied.accepted
            sender.next_send += sender.period

    async def _apply(self, step: Step, t: float) -> None:
        sender = self.sender
        if step.action == "cmd_vel":
            sender.twist, sender.period, sender.next_send = step.value, 1.0 / step.rate, t
        elif step.action == "stop":
            sender.twist, sender.next_send = None, math.inf
        elif step.action == "estop":
            if step.value:
                await self.control.engage_estop("script")
            else:
                self.control.release_estop()
        elif step.action == "stall":
            self.stalled_until = t + step.value
        elif step.action == "autonomy":
            self.autonomy.request(step.value, "script")
        elif step.action == "lidar":
            self.lidar.stalled = step.value == "stall"
            if self.lidar.stalled:
                self.lidar.pending.clear()
            else:
                self.lidar.next_cast = t

    def _lidar_at(self, t: float) -> None:
        feed = self.lidar
        blocked = t + 1e-9 < self.stalled_until
        while feed.pending and feed.pending[0][0] <= t + 1e-9 and not blocked:
            _, scan = feed.pending.pop(0)
            feed.delivered += 1
            self.bus.publish(SCAN, scan)
        if not feed.stalled and t + 1e-9 >= feed.next_cast:
            if self.mapping is not None:
                state = self.world.physics.state
                self.truth_at_cast[t] = (state.x, state.y, state.theta)
            feed.pending.append((t + feed.period, self._cast(t)))
            feed.next_cast = t + feed.period

    def _cast(self, t: float) -> LaserScan:
        sim = self.world.config
        ranges = self.world.scan()
        step = 2.0 * math.pi / len(ranges)
        return LaserScan(stamp=t, frame_id="laser", angle_min=0.0,
                         angle_max=step * (len(ranges) - 1), angle_increment=step,
                         time_increment=self.lidar.period / len(ranges),
                         scan_time=self.lidar.period, range_min=sim.range_min,
                         range_max=sim.range_max, ranges=ranges.astype(np.float32))

    def _track(self) -> None:
        state = self.world.physics.state
        self.coverage.visit(state.x, state.y)
        self._since_clearance += state.travelled
        if self._clearance_bound - self._since_clearance > self.min_clearance:
            return  # cannot be a new minimum yet: it was this far and moved only so much
        clearance = self.truth_clearance()
        self._clearance_bound, self._since_clearance = clearance, 0.0
        self.min_clearance = min(self.min_clearance, clearance)

    def truth_clearance(self) -> float:
        """Ground truth: distance from the footprint to the nearest wall or obstacle (m)."""
        state = self.world.physics.state
        return self.world.world.clearance(state.x, state.y) - \
            self.world.geometry.footprint_radius

    def _mark(self, label: str, t: float) -> None:
        state = self.world.physics.state
        self.marks.append({
            "label": label, "t": round(t, 4), "x": round(state.x, 4), "y": round(state.y, 4),
            "theta": round(state.theta, 4), "v": round(state.v, 4),
            "clearance_m": round(self.truth_clearance(), 4),
            "safety": self.safety.action if self.safety else "disabled",
        })

    # -- the result ----------------------------------------------------------------------------

    def report(self, seconds: float, wall_s: float) -> dict[str, Any]:
        summary = self.world.metrics_summary()
        state = self.world.physics.state
        autonomy = self.autonomy.status()
        return {
            "seconds": seconds, "seed": self.world.config.seed,
            "world": self.world.config.world_file or "generated arena",
            "collisions": summary["collisions"],
            "path_length_m": summary["path_length_m"],
            "mean_speed_m_s": summary["mean_speed_m_s"],
            "max_speed_m_s": summary["max_speed_m_s"],
            "smoothness": {k: summary[k] for k in (
                "rms_linear_acceleration_m_s2", "rms_angular_acceleration_rad_s2",
                "rms_linear_jerk_m_s3", "rms_angular_jerk_rad_s3")},
            "coverage": {"fraction": round(self.coverage.fraction, 4),
                         "visited_cells": self.coverage.visited_free,
                         "free_cells": self.coverage.free_cells,
                         "cell_m": self.coverage.cell},
            "min_clearance_m": round(self.min_clearance, 4),
            "autonomy": {"mode": autonomy["mode"], "state": autonomy["state"],
                         "transitions": autonomy["transitions"],
                         "state_times_s": autonomy["state_times_s"]},
            "safety": self._safety_report(),
            "wheel_guard": self.control.wheel_guard.health(),
            "commands": {"sent": self.sender.sent, "refused": self.sender.refused},
            "lidar_revolutions": self.lidar.delivered,
            "final": {"x": round(state.x, 4), "y": round(state.y, 4),
                      "theta": round(state.theta, 4),
                      "clearance_m": round(self.truth_clearance(), 4)},
            "marks": self.marks,
            **({"mapping": self.mapping.report(self.map_out)} if self.mapping else {}),
            "wall_s": round(wall_s, 3),
            "realtime_factor": round(seconds / wall_s, 1) if wall_s > 0 else None,
        }

    def _safety_report(self) -> dict[str, Any]:
        safety = self.safety
        if safety is None:
            return {"enabled": False}
        return {"enabled": True, "action": safety.action, "changes": safety.changes,
                "first_brake_s": None if self.first_brake is None else round(
                    self.first_brake, 4),
                "stall_stops": self.control.supervisor.stall_stops,
                "entries": dict(safety.entries),
                "time_s": {k: round(v, 3) for k, v in safety.time_in.items()},
                "stop_margin_m": safety.settings.stop_margin}
