# The daemon process: builds components from config, runs them, and shuts down in one place.
from __future__ import annotations

import asyncio
import logging
import signal
import time
from typing import Any

from base.config import Config, ConfigError
from daemon import __version__
from daemon.bus import Bus
from daemon.component import Component, DaemonContext, Plugs
from daemon.components.control.loop import ControlLoop
from daemon.components.http.component import HttpServer
from daemon.components.http.settings import HttpSettings
from daemon.components.sim.component import SimRuntime
from daemon.config import build_driver
from daemon.health import Health, problem_of, worst
from daemon.heap import collect_before_start, freeze_startup_heap, thaw
from daemon.latency import LatencyTracker
from daemon.listen import EXIT_PORT_IN_USE, PortInUse, taken
from daemon.notify import SystemdNotifier
from daemon.registry import COMPONENTS
from daemon.robot import scan_points
from daemon.security import Security
from daemon.settings import DriverSettings, LimitsSettings, RobotSettings, SecuritySettings
from daemon.telemetry import HEALTH, HEALTH_CHANGE, ROBOT_INFO
from daemon.topics import TopicTable
from drivers import DriverError
from sim.settings import SimSettings

log = logging.getLogger("arbiterd")

EXIT_OK, EXIT_FATAL, EXIT_USAGE, EXIT_HARDWARE, EXIT_CONFIG = 0, 1, 2, 69, 78
#: after the start, components still connecting (the lidar's first revolution) are not yet a
#: problem: a state other than ready is logged as INFO until then, and as a WARNING if it lasts
STARTUP_GRACE_S = 5.0

#: Shutdown deadlines, well inside the unit's TimeoutStopSec= (10 s): zeroing the motors may
#: take HALT_TIMEOUT_S (then the driver's emergency path is used), one component's stop()
#: STOP_TIMEOUT_S, all of them together SHUTDOWN_BUDGET_S (then each one left gets
#: MIN_STOP_S). A stop that does not finish in its time is abandoned, and said so.
HALT_TIMEOUT_S = 1.0
STOP_TIMEOUT_S = 3.0
SHUTDOWN_BUDGET_S = 6.0
MIN_STOP_S = 0.25


def health_digest(health: dict[str, Any]) -> tuple[Any, ...]:
    """What counts as a health change: statuses and problem texts, not counters."""
    components = health.get("components", {})
    return (health.get("status"), health.get("state"),
            *((name, c.get("status"), problem_of(c)) for name, c in sorted(components.items())))


def not_ok(health: dict[str, dict[str, Any]], said: str = "") -> str:
    """``lidar degraded: connecting; ...``: the components that are not ok, and why (unless
    ``said`` already says it)."""
    parts = []
    for name, component in health.items():
        status = component.get("status", "error")
        if status != "ok":
            why = problem_of(component) or component.get("state")
            why = "" if why and str(why) in said else why
            parts.append(f"{name} {status}" + (f": {why}" if why else ""))
    return "; ".join(parts)


class StartupError(Exception):
    """A core component could not start (exit code 69: hardware unavailable; 75 when the
    cause is a taken port)."""


class Daemon:
    """Lifecycle: startup -> ready -> degraded/error -> shutdown, with one shutdown path."""

    def __init__(self, config: Config, notifier: SystemdNotifier | None = None) -> None:
        self.config = config
        self.mode = "sim" if config.sim else "hardware"
        self.notifier = notifier or SystemdNotifier()
        self.state = "startup"
        self.started_mono = time.monotonic()
        self.bus = Bus()
        self.latency = LatencyTracker()
        sec = config.get(SecuritySettings)
        self.security = Security(config.token, sec.allowed_origins, sec.read_requires_token,
                                 sec.allowed_hosts)
        self.components: list[Component] = []
        self._plugs: list[Plugs] = []
        self._health_digest: tuple[Any, ...] | None = None
        self._state_unwarned = False  # a state other than ready logged at INFO in the grace
        self.exit_code = EXIT_OK
        self.shutdown_reason = ""
        self._shutdown_requested: asyncio.Event | None = None
        self._shutdown_done = False
        self._tasks: list[asyncio.Task[None]] = []
        self.ctx: DaemonContext | None = None
        #: the control loop, once built (the robot base every component gets as ctx.robot)
        self.control: ControlLoop | None = None
        self.driver_name = self._driver_name()

    # -- building ------------------------------------------------------------------------

    def _driver_name(self) -> str:
        if self.mode == "sim":
            return self.config.get(SimSettings).driver
        return self.config.get(DriverSettings).type

    def _start_simulator(self) -> SimRuntime:
        try:
            runtime = SimRuntime(self.config, [use for spec in COMPONENTS
                                               for use in spec.devices_used(self.config)])
        except ValueError as exc:  # a [sim] value that is wrong only together with others
            raise ConfigError([f"{self.config.source}: {exc}"]) from exc
        try:
            runtime.start_devices()
        except Exception as exc:
            raise StartupError(f"simulated devices: {exc}") from exc
        runtime.apply_to(self.config)
        return runtime

    def _build(self) -> DaemonContext:
        runtime = self._start_simulator() if self.mode == "sim" else None
        self.driver_name = self._driver_name()
        driver = build_driver(self.config, self.driver_name)
        if runtime is not None:
            runtime.attach(driver)
        loop = ControlLoop(self.config, driver, self.bus, self.latency)
        if self.notifier.watchdog_interval_s is not None:  # else its tick hook does nothing
            loop.on_tick.add(self.notifier.tick)
        http = HttpServer(self.config.get(HttpSettings), self.security)
        self.control = loop
        ctx = DaemonContext(self.config, self.bus, http, loop, self.security, self.latency,
                            self.mode, TopicTable(), scan_points(self.config), self,
                            Plugs(loop, loop, self.bus), sim=runtime)
        for spec in COMPONENTS:
            scoped = ctx.scoped()
            self._plugs.append(scoped.plugs)
            try:
                component = spec.create(scoped)
            except ValueError as exc:  # keys valid alone that clash: a configuration error
                raise ConfigError([f"{self.config.source}: [{spec.name}] {exc}"]) from exc
            if component is None:
                continue
            for route in component.routes():
                http.add_route(route.method, route.path, route.handler, access=route.access)
            ctx.topics.declare(component.name, component.topics())
            self.components.append(component)
            ctx.components[spec.name] = component
            log.debug("component %s configured", spec.name)
        return ctx

    # -- running -------------------------------------------------------------------------

    async def run(self) -> int:
        """Start everything, serve until a signal or a fatal error, shut down; exit code."""
        self._shutdown_requested = asyncio.Event()
        self._install_signal_handlers()
        for warning in self.config.warnings:
            log.warning("%s", warning)
        in_use = taken(listener for spec in COMPONENTS
                       for listener in spec.listeners(self.config))
        if in_use is not None:  # before any device is opened: a second one touches nothing
            log.error("cannot start: %s", in_use)
            return EXIT_PORT_IN_USE
        try:
            await self._start()
        except StartupError as exc:
            log.error("startup failed: %s", exc)
            self.exit_code = (EXIT_PORT_IN_USE if isinstance(exc.__cause__, PortInUse)
                              else EXIT_HARDWARE)
            await self.shutdown(f"startup failed: {exc}")
            return self.exit_code
        except ConfigError as exc:
            for problem in exc.problems:
                log.error("configuration error: %s", problem)
            self.exit_code = EXIT_CONFIG
            await self.shutdown("configuration error")
            return self.exit_code
        await self._shutdown_requested.wait()
        await self.shutdown(self.shutdown_reason)
        return self.exit_code

    async def _start(self) -> None:
        self.ctx = self._build()
        log.info("arbiterd %s starting: mode %s, driver %s, config %s", __version__, self.mode,
                 self.driver_name, self.config.source)
        collect_before_start()
        for component in self.components:
            try:
                await component.start()
            except (DriverError, OSError) as exc:
                if component.core:
                    raise StartupError(f"{component.name}: {exc}") from exc
                log.error("%s failed to start: %s", component.name, exc)
        self._tasks.append(asyncio.create_task(self._supervise(), name="supervise"))
        freeze_startup_heap()  # full collections no longer walk what start-up built
        self._update_state()
        self.notifier.ready(self.status_line())
        log.info("ready: %s", self.status_line())

    def request_shutdown(self, reason: str, exit_code: int = EXIT_OK) -> None:
        """Ask the single shutdown path to run (safe from signal handlers and tasks)."""
        if self._shutdown_requested is None or self._shutdown_requested.is_set():
            return
        self.shutdown_reason, self.exit_code = reason, exit_code
        self._shutdown_requested.set()

    async def shutdown(self, reason: str) -> None:
        """The one shutdown path: motors first, then components in reverse, then STOPPING."""
        if self._shutdown_done:
            return
        self._shutdown_done = True
        self.state = "shutdown"
        log.warning("shutting down: %s", reason or "requested")
        self.notifier.stopping(f"stopping: {reason or 'requested'}")
        for task in self._tasks:
            task.cancel()
        control = self.control
        if control is not None:
            await self._halt(control)
        budget_end = time.monotonic() + SHUTDOWN_BUDGET_S
        for component in reversed(self.components):
            timeout = max(MIN_STOP_S, min(STOP_TIMEOUT_S, budget_end - time.monotonic()))
            try:
                async with asyncio.timeout(timeout):
                    await component.stop()
            except TimeoutError:
                log.error("stopping %s took longer than %.2f s; abandoned", component.name,
                          timeout)
            except Exception:
                log.exception("stopping %s failed", component.name)
        for plugs in reversed(self._plugs):
            plugs.release()
        thaw()
        log.info("stopped")

    @staticmethod
    async def _halt(control: ControlLoop) -> None:
        """Latch the shutdown e-stop and zero the motors; if the driver does not take the
        zero within HALT_TIMEOUT_S, its emergency path (no event loop, bounded) does."""
        try:
            async with asyncio.timeout(HALT_TIMEOUT_S):
                await control.halt()
            return
        except TimeoutError:
            log.error("zeroing the motors took longer than %.1f s; using the driver's "
                      "emergency stop", HALT_TIMEOUT_S)
        except Exception:
            log.exception("could not zero the motors; using the driver's emergency stop")
        await asyncio.to_thread(control.driver.emergency_stop)

    def _install_signal_handlers(self) -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, self.request_shutdown, f"signal {sig.name}")

    async def _supervise(self) -> None:
        """Once a second (with a control tick: no wake-up of its own): recompute health
        state, publish it and /robot_info."""
        assert self.control is not None
        control = self.control
        while True:
            self._update_state()
            self._publish_health(self.health())
            self.bus.publish(ROBOT_INFO, self.robot_info())
            await control.sleep_to_tick(1.0)

    def _publish_health(self, health: dict[str, Any]) -> None:
        self.bus.publish(HEALTH, health)
        digest = health_digest(health)
        if digest != self._health_digest:
            self._health_digest = digest
            self.bus.publish(HEALTH_CHANGE, {"t": time.time(), **health})

    # -- reporting -----------------------------------------------------------------------

    def component_health(self) -> dict[str, dict[str, Any]]:
        out = {}
        for component in self.components:
            try:
                health = component.health()
            except Exception as exc:
                health = Health("error", f"health failed: {exc}")
            if health is not None:
                out[component.name] = health.to_json()
        return out

    def overall_status(self, health: dict[str, dict[str, Any]]) -> str:
        statuses = []
        for component in self.components:
            if component.name not in health:
                continue  # nothing to report
            status = health[component.name].get("status", "error")
            statuses.append(status if component.core or status != "error" else "degraded")
        return worst(statuses)

    def _update_state(self) -> None:
        if self.state in ("shutdown",):
            return
        health = self.component_health()
        status = self.overall_status(health)
        state = {"ok": "ready", "degraded": "degraded", "error": "error"}[status]
        starting = time.monotonic() - self.started_mono < STARTUP_GRACE_S
        previous, self.state = self.state, state
        line = self.status_line()
        if state == "ready":
            if previous != state:
                log.info("state: %s", line)
            self._state_unwarned = False
        elif previous != state and starting:
            log.info("state: %s (starting: %s)", line, not_ok(health, line))
            self._state_unwarned = True
        elif previous != state or (self._state_unwarned and not starting):
            log.warning("state: %s (%s)", line, not_ok(health, line))
            self._state_unwarned = False
        self.notifier.status(self.status_line())

    def status_line(self) -> str:
        parts = [self.state, f"{self.mode} mode", f"driver {self.driver_name}"]
        if self.mode == "sim":
            parts.append(f"simulated robot, {self.driver_name} emulator")
        if self.control and self.control.fault:
            parts.append(f"driver fault: {self.control.fault}")
        if self.control and self.control.estop_engaged:
            parts.append("e-stop engaged")
        return ", ".join(parts)

    def health(self) -> dict[str, Any]:
        components = self.component_health()
        return {"status": self.overall_status(components), "state": self.state,
                "mode": self.mode, "version": __version__,
                "uptime_s": round(time.monotonic() - self.started_mono, 3),
                "driver": self.driver_name, "components": components}

    def robot_info(self) -> dict[str, Any]:
        robot = self.config.get(RobotSettings)
        info: dict[str, Any] = {
            "name": robot.name, "version": __version__, "mode": self.mode,
            "driver": self.driver_name,
            "geometry": {"wheel_separation": robot.wheel_separation,
                         "wheel_radius": robot.wheel_radius,
                         "base_frame_id": robot.base_frame_id,
                         "odom_frame_id": robot.odom_frame_id},
            "limits": dict(self.config[LimitsSettings.SECTION]),
        }
        for key, supplier in (self.ctx.robot_info.items() if self.ctx else ()):
            try:
                info[key] = supplier()
            except Exception as exc:
                info[key] = {"error": str(exc)}
        return info
