# The daemon's "recorder" component: bus and log lines into the writer thread, /api/record(ings).
from __future__ import annotations

import asyncio
import json
import logging
import re
import time
from collections.abc import Callable, Sequence
from typing import Any

from aiohttp import web

from daemon import __version__
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, Route
from daemon.components.recorder.channels import Channel, channels_by_bus
from daemon.components.recorder.files import RecordingIndex
from daemon.components.recorder.paths import record_directory
from daemon.components.recorder.settings import RecorderSettings
from daemon.components.recorder.writer import FlightRecorder, WriterOptions
from daemon.files import sees_paths, serve_file, shown
from daemon.health import Health
from daemon.telemetry import POWER, ROBOT_INFO, PowerEvent
from daemon.topics import TopicOut
from daemon.web import ApiError, json_response, read_json_object

log = logging.getLogger("arbiterd.recorder")

_NAME = re.compile(r"^arbiterd-[A-Za-z0-9_-]+\.mcap$")
MB = 1_000_000


class RecorderComponent(BaseComponent):
    """Non-core: a recorder that cannot write degrades health; the robot keeps driving.

    It records every topic of the topic table marked ``record``; the channels are registered
    when it starts, once every component has declared its topics."""

    name = "recorder"
    core = False

    def __init__(self, ctx: DaemonContext, options: RecorderSettings) -> None:
        self.ctx = ctx
        self.bus = ctx.bus
        self.options = options
        self.directory = record_directory({"directory": options.directory})
        self.recorder = FlightRecorder(self._writer_options(), [], self._metadata,
                                       self._on_open)
        self.index = RecordingIndex(self.directory, self.recorder.live_file)
        self._unsubscribers: list[Callable[[], None]] = []
        self._latched: list[tuple[TopicOut[Any], tuple[Channel, ...]]] = []
        #: the recorded topics' bus keys and channels: listened to only while recording is on
        self._groups: list[tuple[TopicOut[Any], tuple[Channel, ...]]] = []

    def _writer_options(self) -> WriterOptions:
        o = self.options
        total = int(o.max_total_mb * MB)
        return WriterOptions(self.directory, min(int(o.max_file_mb * MB), total // 2),
                             o.max_file_s, total, o.compression, o.flush_interval_s,
                             o.queue_size)

    # -- lifecycle --------------------------------------------------------------------------------

    async def start(self) -> None:
        topics = self.ctx.topics.recorded()
        groups = channels_by_bus(topics)
        self.recorder.channels = [c for group in groups.values() for c in group]
        for topic in topics:
            group = groups.pop(topic.bus.name, None)
            if group is None:
                continue  # the bus key's other topics share this group
            self._groups.append((topic, group))
            if topic.latched:
                self._latched.append((topic, group))
        self.set_recording(bool(self.options.enabled))
        self.recorder.start()
        self.ctx.plugs.subscribe(POWER, self._on_power)

    def _on_power(self, event: PowerEvent) -> None:
        """Critical charge: close the file with its summary before the power goes."""
        if event.level == "critical" and self.recorder.wanted:
            log.warning("recorder: closing the recording: %s", event.reason)
            self.set_recording(False)

    def set_recording(self, enabled: bool) -> None:
        """Switch recording on or off; the bus is listened to only while it is on, so a
        recorder that is off costs the publishers (the control tick, every command) nothing."""
        if enabled and not self._unsubscribers:
            self._unsubscribers = [self.bus.subscribe(topic.bus,
                                                      self._enqueuer(group, topic.record_rate))
                                   for topic, group in self._groups]
        elif not enabled:
            self._unsubscribe()
        self.recorder.wanted = enabled

    def _unsubscribe(self) -> None:
        for unsubscribe in self._unsubscribers:
            unsubscribe()
        self._unsubscribers.clear()

    async def stop(self) -> None:
        self._unsubscribe()
        await asyncio.to_thread(self.recorder.stop)

    def health(self) -> Health:
        state = self.recorder.snapshot()
        return Health("degraded" if state["error"] else "ok", state["error"] or "", state)

    def routes(self) -> Sequence[Route]:
        return (Route("POST", "/api/record", self.post_record, "drive"),
                Route("GET", "/api/recordings", self.get_recordings, "read"),
                Route("GET", "/api/recordings/{name}", self.get_recording, "read"))

    # -- feeding the writer (hot path: enqueue only) ----------------------------------------------

    def _enqueuer(self, channels: tuple[Channel, ...],
                  rate: float = 0.0) -> Callable[[Any], None]:
        """What the bus calls per message: into the writer's queue (at most ``rate`` a
        second when it is > 0: the camera's frames)."""
        enqueue = self.recorder.enqueue
        if rate <= 0:
            return lambda message: enqueue(channels, message)
        period, due = 1.0 / rate, [0.0]

        def throttled(message: Any) -> None:
            now = time.monotonic()
            if now >= due[0]:
                # keep the cadence; after a pause, start it afresh
                due[0] = due[0] + period if now - due[0] < period else now + period
                enqueue(channels, message)

        return throttled

    def _on_open(self) -> list[tuple[tuple[Channel, ...], Any]]:
        """Each new file starts with the latest message of every latched topic (health)."""
        out = []
        for topic, group in self._latched:
            latest = self.bus.latest(topic.bus)
            if latest is not None:
                out.append((group, latest))
        return out

    def _metadata(self) -> dict[str, str]:
        info = self.bus.latest(ROBOT_INFO)
        return {"version": __version__, "mode": self.ctx.mode,
                "robot_info": json.dumps(info, default=str) if info is not None else ""}

    # -- HTTP ----------------------------------------------------------------------------------

    async def post_record(self, request: web.Request) -> web.Response:
        body = await read_json_object(request, self.ctx.http.max_body_bytes)
        enabled = body.get("enabled")
        if set(body) != {"enabled"} or not isinstance(enabled, bool):
            raise ApiError(422, 'expected {"enabled": true} or {"enabled": false}',
                           f"got {json.dumps(body)[:200]}")
        self.set_recording(enabled)
        log.info("flight recorder %s through the HTTP API", "enabled" if enabled else "disabled")
        await self._settled(enabled)
        return json_response(self.health().to_json())

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
        return json_response({
            "directory": shown(sees_paths(self.ctx.security, request), str(self.directory)),
            "recordings": [i.to_json(topics=False) for i in infos]})

    async def get_recording(self, request: web.Request) -> web.StreamResponse:
        name = request.match_info["name"]
        missing = f"no recording named {name[:80]!r}"
        if _NAME.match(name) is None:
            raise ApiError(404, missing, "see GET /api/recordings")
        return await serve_file(self.ctx.http, request, self.directory, name,
                                "application/octet-stream", missing)


def create(ctx: DaemonContext) -> RecorderComponent:
    """Build the recorder from ``[recorder]`` (always present: POST /api/record can start it)."""
    return RecorderComponent(ctx, ctx.settings(RecorderSettings))


COMPONENT = ComponentSpec("recorder", create, RecorderSettings)
