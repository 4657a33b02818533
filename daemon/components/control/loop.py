# The control loop: event path (apply on arrival) and tick path (ramps, deadman, odometry).
from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Awaitable, Callable, Coroutine
from dataclasses import dataclass
from typing import Any

from base.config import Config
from base.retrylog import RetryLog
from daemon.bus import Bus
from daemon.clock import MONOTONIC, Clock
from daemon.commands import ZERO, Twist
from daemon.components.control.arbiter import Arbiter, Decision
from daemon.components.control.kinematics import DiffDrive, scale_to_limit
from daemon.components.control.limiter import AxisLimiter, AxisLimits
from daemon.components.control.metronome import Metronome, TimerMetronome, metronome
from daemon.components.control.odometry import Odometry
from daemon.components.control.supervisor import StallSupervisor
from daemon.components.control.wheel_guard import GuardSettings, WheelGuard
from daemon.hooks import HookList, HookMap, Remove, Schedule
from daemon.latency import LatencyTracker
from daemon.motion_guard import MotionGuard
from daemon.robot import Pose2D
from daemon.settings import ControlSettings, LimitsSettings, RobotSettings
from daemon.telemetry import COMMAND, LATENCY_REPORT, ODOM, CommandEvent, LatencyReport, OdomSample
from drivers import DriverError, MotorDriver

log = logging.getLogger("arbiterd.control")


@dataclass(slots=True)
class Applied:
    """What the event path did with one command (made once per command, not changed after:
    not frozen, which would cost four times as much to make)."""

    accepted: bool
    source: str | None
    wheel_rad_s: tuple[float, float]
    clamped: list[str]
    report: LatencyReport | None
    error: str | None = None
    #: what the guard (collision monitor) did on that step: none, slowdown, limit, stop
    guard_action: str | None = None


def _wake(future: asyncio.Future[None]) -> None:
    if not future.done():
        future.set_result(None)


def axis_limits(limits: LimitsSettings, axis: str) -> AxisLimits:
    """The limits of ``linear_x`` or ``angular_z``."""
    def get(key: str) -> float:
        value: float = getattr(limits, f"{axis}_{key}")
        return value

    return AxisLimits(get("max_velocity"), get("max_acceleration"), get("max_deceleration"),
                      get("emergency_deceleration"), get("max_jerk"))


class ControlLoop:
    """Owns the driver, the arbiter, the limiters and odometry (component ``control``)."""

    name = "control"
    core = True

    def __init__(self, config: Config, driver: MotorDriver, bus: Bus,
                 latency: LatencyTracker, clock: Clock = MONOTONIC) -> None:
        control = self.settings = config.get(ControlSettings)
        self.robot = config.get(RobotSettings)
        self.config = config
        #: the one clock of the control code (virtual in ``arbiterd simulate``)
        self.clock = clock
        self.driver = driver
        self.bus = bus
        self.latency = latency
        self.geometry = DiffDrive.from_settings(self.robot)
        limits = config.get(LimitsSettings)
        self.linear = AxisLimiter(axis_limits(limits, "linear_x"))
        self.angular = AxisLimiter(axis_limits(limits, "angular_z"))
        self.arbiter = Arbiter(control.cmd_vel_timeout)
        self.odometry = Odometry(self.geometry)
        self.period_s = 1.0 / control.update_rate
        self.late_s = control.late_tick_ms / 1e3
        #: /odom and /tf at ``publish_rate``: each tick earns the rate, a sample costs the tick
        #: rate (20 Hz of 50 Hz is every 2nd or 3rd tick, not every 2nd)
        self._publish_earned = min(control.publish_rate, control.update_rate)
        self._publish_cost = control.update_rate
        self._publish_credit = 0.0
        #: at rest, how long the zero last written may stand before it is written again
        self.rest_write_s = min(control.rest_write_s, driver.rest_hold_s())
        self._rest_written = -math.inf  # when that zero was written (-inf: write it now)
        self.open_loop = control.open_loop
        #: called with (now, on_time) after every tick
        self.on_tick: HookList[Callable[[float, bool], None]] = HookList()
        #: called at the start of every tick, before the step (internal command sources)
        self.tick_sources: HookList[Callable[[float], None]] = HookList()
        #: callbacks run from the tick when due (periodic reports: no hook every tick)
        self.schedule = Schedule()
        #: called with the source name after every accepted external command
        self.on_command: HookList[Callable[[str], None]] = HookList()
        #: between the arbiter and the limiter for every source (the collision monitor)
        self.guard: MotionGuard | None = None
        self.guard_action: str | None = None
        #: times every source had to send a fresh command (fault, reconnect, stall, e-stop)
        self.invalidations = 0
        #: ... of which because the stall supervisor had stopped the wheels
        self.stall_invalidations = 0
        #: extra fields of /api/status supplied by other components (the simulator's truth)
        self.status_fields: HookMap[Callable[[], Any]] = HookMap()
        self.fault: str | None = None
        self.faults = 0
        self.reconnects = 0
        #: the failed reconnect attempts since the last fault, logged once then now and then
        self.retries = RetryLog(log, "driver reconnect failed")
        self.clamps: dict[str, int] = {}
        self.last_clamped: list[str] = []
        self.wheels = (0.0, 0.0)
        self.decision = Decision(Twist(), None, False, "idle")
        self._lock = asyncio.Lock()
        self._last_step = clock()
        self._tick_task: asyncio.Task[None] | None = None
        self._reconnect_task: asyncio.Task[None] | None = None
        self._metronome: Metronome | TimerMetronome | None = None
        #: zeroes the wheels from its own thread when the tick stops (the loop is blocked)
        self.supervisor = StallSupervisor(driver, self._stall_stop_s(control.stall_stop_s))
        self._ticks = 0
        self._stopping = False
        #: measured wheel speeds, and the stop when they miss the command (a miswired wheel)
        self.wheel_guard = WheelGuard(GuardSettings.from_control(control))
        self.status_fields.add("measured_wheel_speeds_rad_s", self.wheel_guard.status)

    def set_guard(self, guard: MotionGuard) -> Remove:
        """Put ``guard`` between the arbiter and the limiter; returns what takes it out."""
        if self.guard is not None:
            raise ValueError("the control loop already has a guard")
        self.guard = guard

        def remove() -> None:
            if self.guard is guard:
                self.guard, self.guard_action = None, None

        return remove

    # -- lifecycle -----------------------------------------------------------------------

    async def start(self, *, realtime: bool = True) -> None:
        """Open the driver and start ticking in real time; with ``realtime=False`` nobody
        ticks but the caller (:meth:`tick`, the lockstep runner of ``arbiterd simulate``).
        Missing hardware is not fatal: the driver is faulted and reconnects with back-off."""
        try:
            await self.driver.open()
        except DriverError as exc:
            await self._on_fault(f"{self.driver.name()} driver not available: {exc}")
        self._last_step = self.clock()
        if not realtime:
            return
        self._metronome = metronome(asyncio.get_running_loop(), self.period_s)
        self._metronome.start()
        self._tick_task = asyncio.create_task(self._tick_forever(), name="control-tick")
        self.supervisor.start()

    async def stop(self) -> None:
        self._stopping = True
        self.arbiter.engage_estop("shutdown", final=True)
        self.supervisor.stop()  # the tick stops now: that is no stall
        if self._metronome:
            self._metronome.stop()
        for task in (self._tick_task, self._reconnect_task):
            if task:
                task.cancel()
        await self.halt()
        await self.driver.close()

    async def halt(self) -> None:
        """Zero the wheels now (shutdown path): no ramp, it is what stopping the daemon means.
        From here on nothing moves the robot: the e-stop is latched for good (no release) and
        every command is refused."""
        self._stopping = True
        self.arbiter.engage_estop("shutdown", final=True)
        self.linear.reset()
        self.angular.reset()
        async with self._lock:
            await self._write(0.0, 0.0)

    async def sleep_to_tick(self, seconds: float) -> None:
        """Sleep at least ``seconds`` and wake with the next control tick: periodic housekeeping
        then shares the tick's event-loop wake-up instead of waking the process on its own
        (with the thread metronome, or not ticking in real time, a plain sleep)."""
        loop = asyncio.get_running_loop()
        metronome = self._metronome
        if not isinstance(metronome, TimerMetronome):
            await asyncio.sleep(seconds)
            return
        woken = loop.create_future()
        timer = loop.call_at(metronome.next_at(loop.time() + seconds), _wake, woken)
        try:
            await woken
        finally:
            timer.cancel()

    def call_after_tick(self, callback: Callable[[], None]) -> asyncio.Handle:
        """Run ``callback`` in the event-loop wake-up of the next control tick, right after
        the tick: bulk work (a scan's encoding and sends to many clients) that would hold a
        tick up if it ran when it came, as late as one period (with the thread metronome, or
        not ticking in real time: at once)."""
        loop = asyncio.get_running_loop()
        metronome = self._metronome
        if not isinstance(metronome, TimerMetronome):
            return loop.call_soon(callback)
        return loop.call_at(metronome.next_at(loop.time()), callback)

    # -- event path ----------------------------------------------------------------------

    async def submit(self, source: str, twist: Twist, *, t_recv: float,
                     cmd_id: str | int | None = None, t_sent_ms: float | None = None,
                     priority: int = 10, timeout_s: float | None = None) -> Applied:
        """Take a validated command and apply it at once (``t_recv`` = monotonic receipt;
        ``timeout_s``: the source's deadman, None for ``cmd_vel_timeout``). One coroutine
        (the step's lock taken without ``async with``): this runs for every command."""
        refusal = self._refusal_reason()
        if refusal:
            applied = Applied(False, self.decision.source, self.wheels, [], None, refusal)
        else:
            clock = self.clock
            now = clock()
            self._forget_after_stall(now)  # older commands are stale, this one is fresh
            self.arbiter.submit(source, twist, now, priority, timeout_s)
            for callback in self.on_command.snapshot:
                callback(source)
            lock = self._lock
            await lock.acquire()
            try:
                written = await self._step(now)
            finally:
                lock.release()
            applied = self._applied(written, source, t_recv, clock(), cmd_id, t_sent_ms)
        self.bus.publish(COMMAND, CommandEvent(
            time.time(), source, "cmd_vel", twist.linear_x, twist.angular_z, cmd_id,
            applied.accepted, applied.error or ""))
        return applied

    def _applied(self, written: bool, source: str, t_recv: float, t_exec: float,
                 cmd_id: str | int | None, t_sent_ms: float | None) -> Applied:
        """What a step that followed the command did; its latency report on the bus."""
        if not written:
            reason = self._refusal_reason() or "driver did not take the command"
            return Applied(False, self.decision.source, self.wheels, [], None, reason)
        latency = self.latency
        report = latency.report(t_recv, t_exec, source=source, cmd_id=cmd_id,
                                t_sent_ms=t_sent_ms)
        if cmd_id is not None or t_sent_ms is not None:
            self.bus.publish(LATENCY_REPORT, report)  # the sender's answer may leave here
        latency.account(report)
        return Applied(True, self.decision.source, self.wheels, self.last_clamped, report,
                       guard_action=self.guard_action)

    def _refusal_reason(self) -> str | None:
        if self._stopping:
            return "daemon is shutting down"
        if self.arbiter.estop_engaged:
            return "e-stop engaged"
        if self.fault:
            return f"driver fault: {self.fault}"
        return None

    async def drop_source(self, source: str) -> None:
        """A command source went away (WebSocket closed): brake now if it was in charge."""
        self.arbiter.drop(source)
        async with self._lock:
            await self._step(self.clock())

    async def engage_estop(self, reason: str, by: str = "") -> None:
        """Latch the e-stop; ``by`` names who asked, for the log (``HTTP 10.0.0.7``)."""
        self.arbiter.engage_estop(reason)
        self.invalidations += 1
        if by:
            log.warning("e-stop engaged by %s: %s", by, reason)
        else:
            log.warning("e-stop engaged: %s", reason)
        self.bus.publish(COMMAND, CommandEvent(time.time(), reason, "estop"))
        async with self._lock:
            await self._step(self.clock())

    def release_estop(self, by: str = "") -> str | None:
        """Release the e-stop; the reason when it may not be (the daemon is shutting down)."""
        if self._stopping or not self.arbiter.release_estop():
            return "the daemon is shutting down"
        log.warning("e-stop released%s; waiting for a fresh command", f" by {by}" if by else "")
        self.invalidations += 1
        self.bus.publish(COMMAND, CommandEvent(time.time(), "", "estop_release"))
        self.wheel_guard.reset()
        return None

    # -- tick path -----------------------------------------------------------------------

    async def _tick_forever(self) -> None:
        metronome = self._metronome
        assert metronome is not None
        supervisor, latency, tick_now = self.supervisor, self.latency, self._tick_now

        def on_deadline(deadline: float) -> Awaitable[None] | None:
            supervisor.beat()
            latency.missed_ticks = metronome.missed
            return tick_now(deadline)

        await metronome.run(on_deadline)

    async def tick(self, deadline: float) -> None:
        """One tick that was due at ``deadline`` (clock seconds): record its lateness, run
        the internal sources, step, integrate odometry, publish, then the tick callbacks."""
        rest = self._tick_now(deadline)
        if rest is not None:
            await rest

    def _tick_now(self, deadline: float) -> Coroutine[Any, Any, None] | None:
        """The tick as far as it goes without waiting: all of it for a robot at rest (the
        metronome calls this from its own callback), else what is left to await (a step that
        takes the lock and writes the driver, a fault to handle)."""
        now = self.clock()
        lateness = now - deadline
        on_time = lateness <= self.late_s
        self.latency.record_tick(lateness, not on_time)
        try:
            for source in self.tick_sources.snapshot:
                source(now)
            if (self.driver.fault and not self.fault) or self._lock.locked() \
                    or not self._rest_step(now):
                return self._tick_stepping(on_time)
            problem = self._update_odometry(now)
            if problem is not None:
                return self._tick_after(now, on_time, problem)
            self._tick_publish(now)
        except Exception:
            log.exception("control tick failed")
            on_time = False
        self._tick_done(now, on_time)
        return None

    async def _tick_stepping(self, on_time: bool) -> None:
        """The rest of a tick whose step has to wait (lock, driver) or whose driver faulted.
        It runs on the metronome's task, a loop iteration or more after the deadline's
        callback: the step, odometry and what follows take the time they run at, so that a
        pose is stamped with the time its encoders were read (the mapper's odometry history,
        the published /odom) even when that iteration was long."""
        now = self.clock()
        try:
            if self.driver.fault and not self.fault:
                await self._on_fault(self.driver.fault)
            async with self._lock:
                await self._step(now)
            problem = self._update_odometry(now)
        except Exception:
            log.exception("control tick failed")
            self._tick_done(now, False)
            return
        await self._tick_after(now, on_time, problem)

    async def _tick_after(self, now: float, on_time: bool,
                          problem: Coroutine[Any, Any, None] | None) -> None:
        """The rest of a tick after its step and odometry: what the odometry found (a fault,
        a wheel mismatch) handled, then the publications and the tick callbacks."""
        try:
            if problem is not None:
                await problem
            self._tick_publish(now)
        except Exception:
            log.exception("control tick failed")
            on_time = False
        self._tick_done(now, on_time)

    def _tick_publish(self, now: float) -> None:
        """After the step and odometry: the motion guard's pose, odometry, the schedule."""
        if self.guard is not None:
            odo = self.odometry
            self.guard.observe(now, odo.x, odo.y, odo.theta)
        self._ticks += 1
        self._publish_credit += self._publish_earned
        if self._publish_credit >= self._publish_cost:
            self._publish_credit -= self._publish_cost
            self.bus.publish(ODOM, self.odom_sample())
        if now >= self.schedule.next_due:
            self.schedule.run(now)

    def _tick_done(self, now: float, on_time: bool) -> None:
        for callback in self.on_tick.snapshot:
            callback(now, on_time)

    # -- shared step -----------------------------------------------------------------------

    def _rest_step(self, now: float) -> bool:
        """The step of a robot at rest with nothing to follow while the zero written last
        still stands (most ticks of an idle robot): all :meth:`_step` would do, without the
        driver, so without the lock. False when a full step is needed."""
        self._forget_after_stall(now)
        linear, angular = self.linear, self.angular
        if now - self._rest_written >= self.rest_write_s or now <= self._last_step \
                or self.fault or self.guard is not None \
                or not (linear.at_rest() and angular.at_rest()):
            return False
        decision = self.arbiter.decide(now)
        if decision.twist is not ZERO:
            return False
        self.decision, self._last_step = decision, now
        self._settle(decision)
        return True

    def _settle(self, decision: Decision) -> None:
        """At rest with nothing to follow: what the limiters, the geometry and the scaling
        would give (zero everywhere), without them."""
        self.linear.rest()
        self.angular.rest()
        self.last_clamped = []
        if decision.source is None:
            self.arbiter.idle()

    async def _step(self, now: float) -> bool:
        """Arbitrate, limit, convert and write once; True when the driver was written."""
        self._forget_after_stall(now)
        self.decision = decision = self.arbiter.decide(now)
        dt = now - self._last_step
        self._last_step = now
        linear, angular = self.linear, self.angular
        if decision.twist is ZERO and dt > 0.0 and self.guard is None and linear.at_rest() \
                and angular.at_rest():
            self._settle(decision)  # an idle robot: zero is still written
            left = right = 0.0
        else:
            target_v, clamped_v = linear.clamp_target(decision.twist.linear_x)
            target_w, clamped_w = angular.clamp_target(decision.twist.angular_z)
            self.last_clamped = self._target_clamps(clamped_v, clamped_w) \
                if clamped_v or clamped_w else []
            brake = decision.emergency
            if self.guard is not None:
                guarded = self.guard.limit(target_v, target_w, linear.velocity,
                                           angular.velocity, now)
                target_v, target_w = guarded.linear, guarded.angular
                brake = brake or guarded.brake
                self.guard_action = guarded.action
            v = linear.step(target_v, dt, brake)
            w = angular.step(target_w, dt, brake)
            if decision.source is None and v == 0.0 and w == 0.0:
                self.arbiter.idle()
            left, right = self.geometry.wheel_speeds(v, w)
            left, right, scaled = scale_to_limit(left, right, self.driver.max_wheel_speed)
            if scaled:
                self._count_clamp("wheel_speed")
        if self.fault or not self.driver.is_open:
            return False
        try:  # _write, inlined: this runs for every command and every tick
            self.wheels = wheels = await self.driver.set_wheel_speeds(left, right)
        except DriverError as exc:
            await self._on_fault(str(exc))
            return False
        if wheels[0] or wheels[1]:
            self.supervisor.turning()
        self._rest_written = now if wheels == (0.0, 0.0) and decision.twist is ZERO \
            else -math.inf
        return True

    async def _write(self, left: float, right: float) -> bool:
        self._rest_written = -math.inf
        if not self.driver.is_open:
            return False
        try:
            self.wheels = wheels = await self.driver.set_wheel_speeds(left, right)
        except DriverError as exc:
            await self._on_fault(str(exc))
            return False
        if wheels[0] or wheels[1]:
            self.supervisor.turning()
        return True

    def _target_clamps(self, linear: bool, angular: bool) -> list[str]:
        clamped = []
        for name, was_clamped in (("linear.x", linear), ("angular.z", angular)):
            if was_clamped:
                clamped.append(name)
                self._count_clamp(name)
        return clamped

    def _count_clamp(self, name: str) -> None:
        self.clamps[name] = self.clamps.get(name, 0) + 1

    def _update_odometry(self, now: float) -> Coroutine[Any, Any, None] | None:
        """Read the encoders, feed the wheel guard and integrate odometry (nothing here waits:
        drivers keep their latest reading); what to do about a fault or a wheel mismatch."""
        reading = None
        problem: Coroutine[Any, Any, None] | None = None
        if not self.open_loop and not self.fault:
            try:
                reading = self.driver.read_encoders()
            except DriverError as exc:
                return self._on_fault(str(exc))
        if (mismatch := self.wheel_guard.update(reading, self.wheels, now)) is not None:
            problem = self._stop_for(f"wheel mismatch: {mismatch}")
        if reading is not None:
            self.odometry.update_from_encoders(reading.left_rad, reading.right_rad,
                                               reading.t_mono)
        else:
            linear, angular = self.geometry.body_twist(*self.wheels)
            self.odometry.update_open_loop(linear, angular, self.period_s)
        return problem

    # -- faults ------------------------------------------------------------------------------

    def _stall_stop_s(self, configured: float) -> float:
        """``stall_stop_s``, but never less than two tick periods (a late tick is no stall)."""
        floor = 2 * self.period_s
        if 0 < configured < floor:
            log.warning("[control] stall_stop_s = %g is shorter than two control periods at "
                        "update_rate %g Hz; using %g s", configured, 1 / self.period_s, floor)
            return floor
        return configured

    def _forget_after_stall(self, now: float) -> None:
        """The supervisor zeroed the wheels while this loop stood still: every command and the
        ramp state are stale, so the robot waits for a fresh command (as after a reconnect);
        and the wheel guard starts afresh (a stall stop is no miswiring)."""
        supervisor = self.supervisor  # every step asks: the latch is read before the call
        if not supervisor.latched or not supervisor.take_stop():
            return
        self.arbiter.invalidate_all()
        self.invalidations += 1
        self.stall_invalidations += 1
        self._rest_written = -math.inf
        self.linear.reset()
        self.angular.reset()
        self.wheels = (0.0, 0.0)
        self.wheel_guard.restart(now)
        log.warning("control tick running again after a stall stop; wheels stay still until "
                    "a fresh command")

    async def _on_fault(self, reason: str) -> None:
        if self.fault or self._stopping:
            return
        self.fault = reason
        self.faults += 1
        self._rest_written = -math.inf
        log.error("driver fault: %s; motors stopped, reconnecting", reason)
        self.retries.known(reason)
        self.arbiter.invalidate_all()
        self.invalidations += 1
        self.linear.reset()
        self.angular.reset()
        self.driver.report_fault(reason)
        await self.driver.try_zero()  # where the hardware still listens
        self.wheels = (0.0, 0.0)
        self._reconnect_task = asyncio.create_task(self._reconnect(), name="driver-reconnect")

    async def _stop_for(self, reason: str) -> None:
        """Zero the wheels now and latch the e-stop (released by POST /api/estop)."""
        log.error("%s; motors stopped", reason)
        self.arbiter.engage_estop(reason)
        self.linear.reset()
        self.angular.reset()
        async with self._lock:
            await self._write(0.0, 0.0)

    async def _reconnect(self) -> None:
        control = self.settings
        delay = control.reconnect_min_s
        while not self._stopping:
            await self.driver.close()
            await asyncio.sleep(delay)
            try:
                await self.driver.open()
            except DriverError as exc:
                self.retries.failed(str(exc), delay)
                delay = min(delay * 2, control.reconnect_max_s)
                continue
            self.retries.succeeded()
            self.reconnects += 1
            self.odometry.reset_encoder_reference()
            self._rest_written = -math.inf
            self.arbiter.invalidate_all()
            self.invalidations += 1
            self.fault = None
            log.warning("driver reconnected; wheels stay still until a fresh command")
            return

    # -- reports ---------------------------------------------------------------------------

    # -- the robot base as components see it (daemon.robot.RobotBase) ------------------------

    @property
    def estop_engaged(self) -> bool:
        return self.arbiter.estop_engaged

    @property
    def estop_reason(self) -> str:
        return self.arbiter.estop_reason

    def pose(self) -> Pose2D:
        return self.odometry.reported

    def pose_xyt(self) -> tuple[float, float, float]:
        return self.odometry.reported_xyt()

    def integrated_pose(self) -> Pose2D:
        return self.odometry.pose

    def heading(self) -> float:
        return self.odometry.theta

    def odometry_speed(self) -> float:
        return self.odometry.linear

    def limited_velocity(self) -> tuple[float, float]:
        return self.linear.velocity, self.angular.velocity

    def measured_wheel_speeds(self) -> tuple[float, float] | None:
        return self.wheel_guard.measured

    def safety_action(self) -> str:
        action: str = getattr(self.guard, "action", "none")
        return action

    def propose(self, source: str, twist: Twist, now: float, priority: int) -> None:
        self.arbiter.submit(source, twist, now, priority)

    def withdraw(self, source: str) -> None:
        self.arbiter.drop(source)

    def reset_odometry(self, x: float = 0.0, y: float = 0.0, theta: float = 0.0,
                       by: str = "") -> None:
        """Report (x, y, theta) for where the robot stands now, on /odom at once. Only the
        reported frame moves (see :class:`Odometry`): nothing inside the daemon sees a jump."""
        self.odometry.reset(Pose2D(x, y, theta))
        log.info("odometry reset to (%.3f m, %.3f m, %.3f rad)%s", x, y, theta,
                 f" by {by}" if by else "")
        self.bus.publish(ODOM, self.odom_sample())

    def odom_sample(self) -> OdomSample:
        odo, robot, control = self.odometry, self.robot, self.settings
        x, y, theta = odo.reported_xyt()
        return OdomSample(time.time(), robot.odom_frame_id, robot.base_frame_id, x, y, theta,
                          odo.linear, odo.angular,
                          control.pose_covariance_diagonal,
                          control.twist_covariance_diagonal)

    def status(self) -> dict[str, Any]:
        pose = self.odometry.reported
        return {
            "pose": {"x": pose.x, "y": pose.y, "theta": pose.theta,
                     "theta_deg": math.degrees(pose.theta)},
            "twist": {"linear_x": self.linear.velocity, "angular_z": self.angular.velocity},
            "target": {"linear_x": self.decision.twist.linear_x,
                       "angular_z": self.decision.twist.angular_z},
            "wheel_speeds_rad_s": {"left": self.wheels[0], "right": self.wheels[1]},
            "active_source": self.decision.source,
            "reason": self.decision.reason,
            "estop": {"engaged": self.arbiter.estop_engaged,
                      "reason": self.arbiter.estop_reason},
            "clamps": dict(self.clamps),
            "last_clamped": list(self.last_clamped),
            "fault": self.fault,
            **{key: supply() for key, supply in self.status_fields.items()},
        }

    def health(self) -> dict[str, Any]:
        stall = self.supervisor.health()
        status = "error" if self.fault or stall["stalled"] or self.wheel_guard.tripped else "ok"
        return {"status": status, "fault": self.fault, "faults": self.faults,
                "reconnects": self.reconnects,
                "reconnect_attempts": self.retries.attempts, "driver": self.driver.health(),
                "estop": self.arbiter.estop_engaged, "wheel_guard": self.wheel_guard.health(),
                **stall}
