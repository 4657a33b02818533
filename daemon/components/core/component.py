# The daemon's own component: health, latency, robot info and metrics, its topics, /rosout.
from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any, cast

from aiohttp import web

from daemon.bus import Bus
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, Reports, Route
from daemon.latency import LatencyTracker
from daemon.logthrottle import RepeatFilter
from daemon.messages.convert import diagnostics_msg, json_string_msg, log_msg
from daemon.messages.definitions import DIAGNOSTIC_ARRAY, LOG, STRING
from daemon.metrics import prometheus_text
from daemon.security import Security, hide_paths
from daemon.settings import SecuritySettings
from daemon.telemetry import HEALTH_CHANGE, LOG_RECORD, ROBOT_INFO
from daemon.topics import Topic, TopicOut
from daemon.web import json_response


class CoreApi(BaseComponent):
    """``/api/health``, ``/api/latency``, ``/api/robot_info`` and ``/metrics``; the topics
    ``/robot_info``, ``/diagnostics`` (recorded on every health change) and ``/rosout`` (the
    daemon's log lines, INFO and up)."""

    name = "core"

    def __init__(self, reports: Reports, latency: LatencyTracker, bus: Bus,
                 open_health: bool, security: Security | None = None) -> None:
        self.reports = reports
        self.latency = latency
        self.bus = bus
        self.open_health = open_health
        self.security = security or Security("")
        self._relay: LogRelay | None = None

    async def start(self) -> None:
        self._relay = LogRelay(self.bus, asyncio.get_running_loop())
        logging.getLogger().addHandler(self._relay)

    async def stop(self) -> None:
        if self._relay is not None:
            logging.getLogger().removeHandler(self._relay)
            self._relay = None

    def health(self) -> None:
        return None

    def routes(self) -> Sequence[Route]:
        return (Route("GET", "/api/health", self.get_health,
                      "open" if self.open_health else "read"),
                Route("GET", "/api/latency", self.get_latency, "read"),
                Route("GET", "/api/robot_info", self.get_robot_info, "read"),
                Route("GET", "/metrics", self.get_metrics, "read"))

    def topics(self) -> Sequence[Topic]:
        return (TopicOut("/robot_info", STRING, ROBOT_INFO, json_string_msg, "1 Hz",
                         record=False),
                TopicOut("/diagnostics", DIAGNOSTIC_ARRAY, HEALTH_CHANGE, diagnostics_msg,
                         "on change", bridge=False, latched=True),
                TopicOut("/rosout", LOG, LOG_RECORD, self._log_msg(), "per log line",
                         state=False))

    def _log_msg(self) -> Callable[[logging.LogRecord], dict[str, Any]]:
        """/rosout's converter: with a token configured its subscribers may be read-only
        clients, so paths in the lines (and the source file) are hidden for every one; the
        journal keeps them."""
        if not self.security.token_required:
            return log_msg
        return lambda record: cast(dict[str, Any], hide_paths(log_msg(record)))

    async def get_health(self, request: web.Request) -> web.Response:
        body = self.reports.health()
        status = 503 if body["status"] == "error" else 200
        if not self.security.sees_paths(request.headers, request.query,
                                        request.remote):
            body = hide_paths(body)
        return json_response(body, status=status)

    async def get_latency(self, request: web.Request) -> web.Response:
        return json_response(self.latency.stats())

    async def get_robot_info(self, request: web.Request) -> web.Response:
        return json_response(self.reports.robot_info())

    async def get_metrics(self, request: web.Request) -> web.Response:
        text = prometheus_text(self.reports.health(), self.latency.stats(),
                               self.latency.metrics.registry)
        return web.Response(text=text, content_type="text/plain", charset="utf-8")


class LogRelay(logging.Handler):
    """Publishes the daemon's log lines (INFO and up) on the bus, on the event loop's thread:
    a line logged by another thread is formatted there and handed over. A line logged while
    one is being published (a subscriber that logs) is not published again."""

    def __init__(self, bus: Bus, loop: asyncio.AbstractEventLoop) -> None:
        super().__init__(logging.INFO)
        self.addFilter(RepeatFilter())  # /rosout and the recording: no flood either
        self.bus = bus
        self.loop = loop
        self.thread = threading.get_ident()
        self._publishing = False

    def emit(self, record: logging.LogRecord) -> None:
        if not self.bus.subscribers(LOG_RECORD):
            return  # nobody records or serves /rosout: no copy, no hand-over
        try:
            copy = logging.makeLogRecord(record.__dict__)
            copy.msg, copy.args = record.getMessage(), None  # later changes to args don't count
            if threading.get_ident() == self.thread:
                self._publish(copy)
            elif not self.loop.is_closed():
                with contextlib.suppress(RuntimeError):  # the loop is shutting down
                    self.loop.call_soon_threadsafe(self._publish, copy)
        except Exception:
            self.handleError(record)

    def _publish(self, record: logging.LogRecord) -> None:
        if self._publishing:
            return
        self._publishing = True
        try:
            self.bus.publish(LOG_RECORD, record)
        finally:
            self._publishing = False


def create(ctx: DaemonContext) -> CoreApi:
    return CoreApi(ctx.reports, ctx.latency, ctx.bus, ctx.settings(SecuritySettings).open_health,
                   ctx.security)


COMPONENT = ComponentSpec("core", create)
