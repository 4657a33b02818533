# The daemon process: builds components from config, runs them, and shuts down in one place.
from __future__ import annotations

import asyncio
import logging
import signal
import time
from collections.abc import Callable
from typing import Any

from aiohttp import web

from daemon import __version__, console, lidar
from daemon.autonomy import component as autonomy
from daemon.bus import Bus
from daemon.component import Component, DaemonContext, worst
from daemon.config import Config, ConfigError, build_driver
from daemon.control.api import ControlApi
from daemon.control.loop import ControlLoop
from daemon.http_api import Access, HttpServer, json_response
from daemon.latency import LatencyTracker
from daemon.metrics import prometheus_text
from daemon.notify import SystemdNotifier
from daemon.recorder import component as recorder
from daemon.rosbridge import server as rosbridge_server
from daemon.safety import component as safety
from daemon.security import Security
from drivers import DriverError

log = logging.getLogger("arbiterd")

EXIT_OK, EXIT_FATAL, EXIT_USAGE, EXIT_HARDWARE, EXIT_CONFIG = 0, 1, 2, 69, 78

# component name => factory; it takes the DaemonContext and returns a Component, or None when
# its config section disables it. Started in this order.
COMPONENTS: dict[str, Callable[[DaemonContext], Component | None]] = {
    "lidar": lidar.create,
    "collision_monitor": safety.create,
    "autonomy": autonomy.create,
    "rosbridge": rosbridge_server.create,
    "recorder": recorder.create,
}


class StartupError(Exception):
    """A core component could not start (exit code 69: hardware unavailable)."""


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
        sec = config["security"]
        self.security = Security(config.token, sec["allowed_origins"],
                                 sec["read_requires_token"], sec["allowed_hosts"])
        self.components: list[Component] = []
        self.exit_code = EXIT_OK
        self.shutdown_reason = ""
        self._shutdown_requested: asyncio.Event | None = None
        self._shutdown_done = False
        self._tasks: list[asyncio.Task[None]] = []
        self.ctx: DaemonContext | None = None
        self.driver_name = self._driver_name()

    # -- building ------------------------------------------------------------------------

    def _driver_name(self) -> str:
        if self.mode == "sim":
            return str(self.config["sim"]["driver"])
        return str(self.config["driver"]["type"])

    def _start_simulator(self) -> Any:
        from daemon.simulator import SimRuntime

        try:
            runtime = SimRuntime(self.config)
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
        control = self.config["control"]
        driver = build_driver(self.config, self.driver_name)
        loop = ControlLoop(self.config, driver, self.bus, self.latency)
        http_cfg = self.config["http"]
        http = HttpServer(http_cfg, self.security)
        ctx = DaemonContext(self.config, self.bus, http, loop, self.security, self.latency,
                            self.mode)
        ControlApi(loop, http, control["allow_fault_injection"])
        loop.on_tick.append(self.notifier.tick)
        self._add_own_routes(http)
        if http_cfg["console"]:
            console.register(http, self.config)
        self.components = [loop]
        if runtime is not None:
            runtime.attach(driver)
            runtime.register(http, self.bus, loop.status_extras)
            self.components.insert(0, runtime)
        for name, factory in COMPONENTS.items():
            component = factory(ctx)
            if component is not None:
                self.components.append(component)
                log.debug("component %s configured", name)
        if http_cfg["enabled"]:
            self.components.append(http)
        return ctx

    def _add_own_routes(self, http: HttpServer) -> None:
        health_access: Access = "open" if self.config["security"]["open_health"] else "read"
        http.add_route("GET", "/api/health", self._get_health, access=health_access)
        http.add_route("GET", "/api/latency", self._get_latency, access="read")
        http.add_route("GET", "/api/robot_info", self._get_robot_info, access="read")
        http.add_route("GET", "/metrics", self._get_metrics, access="read")

    # -- running -------------------------------------------------------------------------

    async def run(self) -> int:
        """Start everything, serve until a signal or a fatal error, shut down; exit code."""
        self._shutdown_requested = asyncio.Event()
        self._install_signal_handlers()
        for warning in self.config.warnings:
            log.warning("%s", warning)
        try:
            await self._start()
        except StartupError as exc:
            log.error("startup failed: %s", exc)
            self.exit_code = EXIT_HARDWARE
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
        for component in self.components:
            try:
                await component.start()
            except (DriverError, OSError) as exc:
                if component.core:
                    raise StartupError(f"{component.name}: {exc}") from exc
                log.error("%s failed to start: %s", component.name, exc)
        self._tasks.append(asyncio.create_task(self._supervise(), name="supervise"))
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
        control = self.ctx.control if self.ctx else None
        if control is not None:
            try:
                await control.halt()
            except Exception:
                log.exception("could not zero the motors")
        for component in reversed(self.components):
            try:
                await component.stop()
            except Exception:
                log.exception("stopping %s failed", component.name)
        log.info("stopped")

    def _install_signal_handlers(self) -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, self.request_shutdown, f"signal {sig.name}")

    async def _supervise(self) -> None:
        """Once a second: recompute health state, publish it and /robot_info."""
        while True:
            self._update_state()
            self.bus.publish("health", self.health())
            self.bus.publish("robot_info", self.robot_info())
            await asyncio.sleep(1.0)

    # -- reporting -----------------------------------------------------------------------

    def component_health(self) -> dict[str, dict[str, Any]]:
        out = {}
        for component in self.components:
            try:
                out[component.name] = component.health()
            except Exception as exc:
                out[component.name] = {"status": "error", "error": f"health failed: {exc}"}
        return out

    def overall_status(self, health: dict[str, dict[str, Any]]) -> str:
        statuses = []
        for component in self.components:
            status = health.get(component.name, {}).get("status", "error")
            statuses.append(status if component.core or status != "error" else "degraded")
        return worst(statuses)

    def _update_state(self) -> None:
        if self.state in ("shutdown",):
            return
        status = self.overall_status(self.component_health())
        state = {"ok": "ready", "degraded": "degraded", "error": "error"}[status]
        if state != self.state:
            self.state = state
            log.warning("state: %s", self.status_line()) if state != "ready" else log.info(
                "state: %s", self.status_line())
        self.notifier.status(self.status_line())

    def status_line(self) -> str:
        parts = [self.state, f"{self.mode} mode", f"driver {self.driver_name}"]
        if self.mode == "sim":
            parts.append(f"simulated robot, {self.driver_name} emulator")
        if self.ctx and self.ctx.control.fault:
            parts.append(f"driver fault: {self.ctx.control.fault}")
        if self.ctx and self.ctx.control.arbiter.estop_engaged:
            parts.append("e-stop engaged")
        for note in (self.ctx.extras.get("status_notes", []) if self.ctx else []):
            parts.append(note)
        return ", ".join(parts)

    def health(self) -> dict[str, Any]:
        components = self.component_health()
        return {"status": self.overall_status(components), "state": self.state,
                "mode": self.mode, "version": __version__,
                "uptime_s": round(time.monotonic() - self.started_mono, 3),
                "driver": self.driver_name, "components": components}

    def robot_info(self) -> dict[str, Any]:
        robot, limits = self.config["robot"], self.config["limits"]
        info: dict[str, Any] = {
            "name": robot["name"], "version": __version__, "mode": self.mode,
            "driver": self.driver_name,
            "geometry": {k: robot[k] for k in ("wheel_separation", "wheel_radius",
                                               "base_frame_id", "odom_frame_id")},
            "limits": dict(limits),
        }
        for key, supplier in (self.ctx.robot_info.items() if self.ctx else ()):
            try:
                info[key] = supplier()
            except Exception as exc:
                info[key] = {"error": str(exc)}
        return info

    async def _get_health(self, request: web.Request) -> web.Response:
        body = self.health()
        return json_response(body, status=503 if body["status"] == "error" else 200)

    async def _get_latency(self, request: web.Request) -> web.Response:
        return json_response(self.latency.stats())

    async def _get_robot_info(self, request: web.Request) -> web.Response:
        return json_response(self.robot_info())

    async def _get_metrics(self, request: web.Request) -> web.Response:
        text = prometheus_text(self.health(), self.latency.stats(),
                               self.latency.metrics.registry)
        return web.Response(text=text, content_type="text/plain", charset="utf-8")

