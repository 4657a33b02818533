# The daemon's "lidar" component: runs the device manager, publishes /scan, serves /api/scan.
from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Sequence
from typing import Any

from aiohttp import web

from daemon.component import BaseComponent, ComponentSpec, DaemonContext, Route
from daemon.health import Health
from daemon.messages.convert import scan_msg, tf_msg
from daemon.messages.definitions import LASER_SCAN, TF_MESSAGE
from daemon.settings import RobotSettings
from daemon.telemetry import SCAN, STATIC_TRANSFORMS, Transform
from daemon.topics import Topic, TopicOut
from daemon.web import ApiError
from sensors.rplidar.assembler import Revolution, ScanGeometry, to_laser_scan
from sensors.rplidar.client import open_serial
from sensors.rplidar.device import LidarManager, ManagerConfig, OpenPort
from sensors.rplidar.settings import LidarSettings
from sensors.scan import LaserScan

log = logging.getLogger(__name__)


def manager_config(options: LidarSettings) -> ManagerConfig:
    return ManagerConfig(
        port=options.port, baudrate=options.baudrate, scan_mode=options.scan_mode,
        motor_pwm=options.motor_pwm, request_timeout=options.request_timeout_s,
        revolution_timeout=options.revolution_timeout_s,
        reconnect_max=options.reconnect_max_s, error_retry=options.error_retry_s)


class LidarComponent(BaseComponent):
    """Non-core: a missing or failing lidar degrades health, it never stops the daemon."""

    name = "lidar"
    core = False

    def __init__(self, bus: Any, options: LidarSettings,
                 open_port: OpenPort = open_serial, base_frame_id: str = "base_link") -> None:
        self.bus = bus
        self.options = options
        self.base_frame_id = base_frame_id
        self.manager = LidarManager(manager_config(options), self._on_revolution, open_port)
        self.latest: LaserScan | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self.bus.publish(STATIC_TRANSFORMS, (self.mount(),))
        self.manager.start()

    def mount(self) -> Transform:
        """Where the lidar sits on the robot: ``base_link -> laser`` for /tf_static."""
        o = self.options
        return Transform(time.time(), self.base_frame_id, o.frame_id, o.mount_x, o.mount_y,
                         math.radians(o.mount_yaw_deg))

    async def stop(self) -> None:
        await asyncio.to_thread(self.manager.stop)

    def health(self) -> Health:
        report = self.manager.snapshot()
        return Health.of(report, "last_error", otherwise=str(report["state"]))

    def routes(self) -> Sequence[Route]:
        return (Route("GET", "/api/scan", self.get_scan, "read"),)

    def topics(self) -> Sequence[Topic]:
        return (TopicOut("/scan", LASER_SCAN, SCAN, scan_msg, "per revolution", bulk=True),
                TopicOut("/tf_static", TF_MESSAGE, STATIC_TRANSFORMS, tf_msg, "once",
                         latched=True))

    def info(self) -> dict[str, Any]:
        s = self.manager.state
        return {"model": s.model, "firmware": s.firmware, "hardware": s.hardware,
                "serial": s.serial, "mode": s.mode}

    def geometry(self) -> ScanGeometry:
        plan = self.manager.plan
        o = self.options
        range_max = o.range_max or (plan.max_distance_m if plan else 0) or 12.0
        return ScanGeometry(frame_id=o.frame_id, inverted=o.inverted,
                            angle_offset_deg=o.angle_offset_deg, bins=o.angle_bins,
                            range_min=o.range_min, range_max=range_max)

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
        self.bus.publish(SCAN, scan)

    async def get_scan(self, request: web.Request) -> web.Response:
        if self.latest is None:
            raise ApiError(404, "no scan yet", {"lidar_state": self.manager.state.state})
        return web.json_response(self.latest.to_json())


def create(ctx: DaemonContext) -> LidarComponent | None:
    """Build the lidar component from ``[lidar]``; None when disabled."""
    options = ctx.settings(LidarSettings)
    if not options.enabled:
        return None
    component = LidarComponent(ctx.bus, options,
                               base_frame_id=ctx.settings(RobotSettings).base_frame_id)
    ctx.add_robot_info("lidar", component.info)
    return component


COMPONENT = ComponentSpec("lidar", create, LidarSettings)
