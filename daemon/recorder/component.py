# The daemon's "recorder" component: bus and log lines into the writer thread, /api/record(ings).
from __future__ import annotations

import asyncio
import json
import logging
import re
import time
from collections.abc import Callable
from typing import Any

from aiohttp import web

from base.options import defaults
from daemon import __version__
from daemon.http_api import ApiError, json_response, read_json_object
from daemon.recorder.channels import (
    ROSOUT,
    Channel,
    bus_channels,
    health_digest,
    log_record_source,
)
from daemon.recorder.files import RecordingIndex
from daemon.recorder.paths import record_directory
from daemon.recorder.writer import FlightRecorder, WriterOptions
from daemon.settings import RECORD_OPTIONS

log = logging.getLogger("arbiterd.recorder")

_NAME = re.compile(r"^arbiterd-[A-Za-z0-9_-]+\.mcap$")
MB = 1_000_000


class RecorderComponent:
    """Non-core: a recorder that cannot write degrades health; the robot keeps driving."""

    name = "recorder"
    core = False

    def __init__(self, ctx: Any, options: dict[str, Any]) -> None:
        self.ctx = ctx
        self.bus = ctx.bus
        self.options = options
        self.directory = record_directory(options)
        self.channels = bus_channels(sim=ctx.mode == "sim",
                                     odom_tf=ctx.config["control"]["enable_odom_tf"])
        all_channels = [c for group in self.channels.values() for c in group] + [ROSOUT]
        self.recorder = FlightRecorder(self._writer_options(), all_channels,
                                       self._metadata, self._on_open)
        self.index = RecordingIndex(self.directory, self.recorder.live_file)
        self._unsubscribers: list[Callable[[], None]] = []
        self._log_handler: RecordLogHandler | None = None
        self._health: tuple[Any, ...] | None = None

    def _writer_options(self) -> WriterOptions:
        o = self.options
        total = int(o["max_total_mb"] * MB)
        return WriterOptions(self.directory, min(int(o["max_file_mb"] * MB), total // 2),
                             o["max_file_s"], total, o["compression"], o["flush_interval_s"],
                             o["queue_size"])

    # -- lifecycle --------------------------------------------------------------------------------

    async def start(self) -> None:
        for topic, channels in self.channels.items():
            handler = self._health_changed if topic == "health" else self._enqueuer(channels)
            self._unsubscribers.append(self.bus.subscribe(topic, handler))
        self._log_handler = RecordLogHandler(self.recorder)
        logging.getLogger().addHandler(self._log_handler)
        self.recorder.wanted = bool(self.options["enabled"])
        self.recorder.start()

    async def stop(self) -> None:
        for unsubscribe in self._unsubscribers:
            unsubscribe()
        self._unsubscribers.clear()
        await asyncio.to_thread(self.recorder.stop)
        if self._log_handler is not None:
            logging.getLogger().removeHandler(self._log_handler)
            self._log_handler = None

    def health(self) -> dict[str, Any]:
        state = self.recorder.snapshot()
        state["status"] = "degraded" if state["error"] else "ok"
        return state

    # -- feeding the writer (hot path: enqueue only) ----------------------------------------------

    def _enqueuer(self, channels: list[Channel]) -> Callable[[Any], None]:
        group = tuple(channels)
        enqueue = self.recorder.enqueue
        return lambda message: enqueue(group, message)

    def _health_changed(self, health: dict[str, Any]) -> None:
        digest = health_digest(health)
        if digest != self._health:
            self._health = digest
            self.recorder.enqueue(tuple(self.channels["health"]), {"t": time.time(), **health})

    def _on_open(self) -> list[tuple[tuple[Channel, ...], Any]]:
        """Each new file starts with the current health (writer thread)."""
        health = self.bus.latest("health")
        if health is None:
            return []
        return [(tuple(self.channels["health"]), {"t": time.time(), **health})]

    def _metadata(self) -> dict[str, str]:
        info = self.bus.latest("robot_info")
        return {"version": __version__, "mode": self.ctx.mode,
                "robot_info": json.dumps(info, default=str) if info is not None else ""}

    # -- HTTP ----------------------------------------------------------------------------------

    async def post_record(self, request: web.Request) -> web.Response:
        body = await read_json_object(request, self.ctx.http.max_body_bytes)
        enabled = body.get("enabled")
        if set(body) != {"enabled"} or not isinstance(enabled, bool):
            raise ApiError(422, 'expected {"enabled": true} or {"enabled": false}',
                           f"got {json.dumps(body)[:200]}")
        self.recorder.wanted = enabled
        log.info("flight recorder %s through the HTTP API", "enabled" if enabled else "disabled")
        await self._settled(enabled)
        return json_response(self.health())

    async def _settled(self, enabled: bool, within_s: float = 3.0) -> None:
        """Wait (briefly) until the writer thread opened or closed its file, or failed."""
        deadline = time.monotonic() + within_s
        while time.monotonic() < deadline:
            recording = self.recorder.current is not None
            if recording == enabled or (enabled and self.recorder.error):
                return
            await asyncio.sleep(0.02)

    async def get_recordings(self, request: web.Request) -> web.Response:
        infos = await asyncio.to_thread(self.index.list)
        current = self.recorder.current
        return json_response({
            "directory": str(self.directory),
            "recordings": [{**i.to_json(topics=False),
                            "recording": current is not None and current.name == i.name}
                           for i in infos]})

    async def get_recording(self, request: web.Request) -> web.StreamResponse:
        name = request.match_info["name"]
        path = self.directory / name
        if _NAME.match(name) is None or not path.is_file():
            raise ApiError(404, f"no recording named {name!r}", "see GET /api/recordings")
        return web.FileResponse(path, headers={
            "Content-Type": "application/octet-stream",
            "Content-Disposition": f'attachment; filename="{name}"'})


class RecordLogHandler(logging.Handler):
    """Copies the daemon's log lines (INFO and up) into the recording as /rosout."""

    def __init__(self, recorder: FlightRecorder) -> None:
        super().__init__(logging.INFO)
        self.recorder = recorder
        self.group = (ROSOUT,)

    def emit(self, record: logging.LogRecord) -> None:
        if self.recorder.wanted:
            self.recorder.enqueue(self.group, log_record_source(record))


def create(ctx: Any) -> RecorderComponent:
    """Build the recorder from ``[record]`` (always present: POST /api/record can start it)."""
    options = defaults(RECORD_OPTIONS) | dict(ctx.config["record"])
    component = RecorderComponent(ctx, options)
    ctx.http.add_route("POST", "/api/record", component.post_record, access="drive")
    ctx.http.add_route("GET", "/api/recordings", component.get_recordings, access="read")
    ctx.http.add_route("GET", "/api/recordings/{name}", component.get_recording,
                       access="read")
    return component
