# The daemon's "lidar" component: runs the device manager, publishes "scan", serves /api/scan.
from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import Any

from aiohttp import web

from base.options import defaults
from daemon.http_api import ApiError
from sensors.rplidar.assembler import Revolution, ScanGeometry, to_laser_scan
from sensors.rplidar.client import open_serial
from sensors.rplidar.device import LidarManager, ManagerConfig, OpenPort
from sensors.rplidar.settings import LIDAR_OPTIONS
from sensors.scan import LaserScan

log = logging.getLogger(__name__)


def manager_config(options: dict[str, Any]) -> ManagerConfig:
    return ManagerConfig(
        port=options["port"], baudrate=options["baudrate"], scan_mode=options["scan_mode"],
        motor_pwm=options["motor_pwm"], request_timeout=options["request_timeout_s"],
        revolution_timeout=options["revolution_timeout_s"],
        reconnect_max=options["reconnect_max_s"], error_retry=options["error_retry_s"])


class LidarComponent:
    """Non-core: a missing or failing lidar degrades health, it never stops the daemon."""

    name = "lidar"
    core = False

    def __init__(self, bus: Any, options: dict[str, Any],
                 open_port: OpenPort = open_serial) -> None:
        self.bus = bus
        self.options = options
        self.manager = LidarManager(manager_config(options), self._on_revolution, open_port)
        self.latest: LaserScan | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self.manager.start()

    async def stop(self) -> None:
        await asyncio.to_thread(self.manager.stop)

    def health(self) -> dict[str, Any]:
        return self.manager.snapshot()

    def info(self) -> dict[str, Any]:
        s = self.manager.state
        return {"model": s.model, "firmware": s.firmware, "hardware": s.hardware,
                "serial": s.serial, "mode": s.mode}

    def geometry(self) -> ScanGeometry:
        plan = self.manager.plan
        range_max = self.options["range_max"] or (plan.max_distance_m if plan else 0) or 12.0
        return ScanGeometry(frame_id=self.options["frame_id"], inverted=self.options["inverted"],
                            angle_offset_deg=self.options["angle_offset_deg"],
                            bins=self.options["angle_bins"], range_min=self.options["range_min"],
                            range_max=range_max)

    def _on_revolution(self, rev: Revolution) -> None:
        """Reader thread: convert here (numpy, off the event loop), hand over to the loop."""
        scan = to_laser_scan(rev, self.geometry())
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        with contextlib.suppress(RuntimeError):  # the loop is shutting down
            loop.call_soon_threadsafe(self._publish, scan)

    def _publish(self, scan: LaserScan) -> None:
        self.latest = scan
        self.bus.publish("scan", scan)

    async def get_scan(self, request: web.Request) -> web.Response:
        if self.latest is None:
            raise _api_error(404, "no scan yet", self.manager.state.state)
        return web.json_response(self.latest.to_json())


def _api_error(status: int, message: str, detail: Any) -> Exception:
    return ApiError(status, message, {"lidar_state": detail})


def create(ctx: Any) -> LidarComponent | None:
    """Build the lidar component from ``[lidar]``; None when disabled."""
    options = defaults(LIDAR_OPTIONS) | dict(ctx.config["lidar"])
    if not options["enabled"]:
        return None
    component = LidarComponent(ctx.bus, options)
    ctx.http.add_route("GET", "/api/scan", component.get_scan, access="read")
    robot_info = getattr(ctx, "robot_info", None)
    if isinstance(robot_info, dict):
        robot_info["lidar"] = component.info
    return component
