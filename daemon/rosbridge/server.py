# The rosbridge v2 WebSocket component (:9090): admission, bus fan-out, /rosout, services.
from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from aiohttp import WSCloseCode, web

from daemon.rosbridge.access import Authority
from daemon.rosbridge.graph import BridgeGraph, Topic
from daemon.rosbridge.outbox import SharedMessage
from daemon.rosbridge.session import ClientSession
from daemon.rosbridge.topics import log_msg, robot_topics

if TYPE_CHECKING:
    from daemon.component import DaemonContext

log = logging.getLogger("arbiterd.rosbridge")


def create(ctx: DaemonContext) -> RosbridgeServer | None:
    """Component factory (``daemon.app.COMPONENTS``); None when ``[rosbridge] enabled = false``."""
    if not ctx.config["rosbridge"]["enabled"]:
        return None
    return RosbridgeServer(ctx)


class RosbridgeServer:
    """Serves rosbridge v2 on ``ws://host:port/`` and bridges it to the control loop and bus."""

    name = "rosbridge"
    core = False

    def __init__(self, ctx: DaemonContext) -> None:
        cfg = ctx.config["rosbridge"]
        self.ctx = ctx
        self.control = ctx.control
        self.security = ctx.security
        self.host: str = cfg["host"]
        self.port: int = cfg["port"]
        self.max_clients: int = cfg["max_clients"]
        self.max_message_bytes: int = cfg["max_message_bytes"]
        self.graph = BridgeGraph(robot_topics(
            sim=ctx.mode == "sim", odom_tf=ctx.config["control"]["enable_odom_tf"]),
            latest=ctx.bus.latest)
        self.clients: dict[int, ClientSession] = {}
        self.refused = {"origin": 0, "token": 0, "full": 0}
        self.connections = 0
        self.bound_port: int | None = None
        self._runner: web.AppRunner | None = None
        self._bus_unsubscribers: list[Callable[[], None]] = []
        self._log_handler: RosoutHandler | None = None

    # -- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> None:
        app = web.Application()
        app.router.add_get("/", self._handle)
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port, reuse_address=True)
        try:
            await site.start()
        except OSError:
            await self._runner.cleanup()
            self._runner = None
            raise
        server = getattr(site, "_server", None)
        sockets = getattr(server, "sockets", None) or []
        self.bound_port = sockets[0].getsockname()[1] if sockets else self.port
        self._wire_bus()
        self._log_handler = RosoutHandler(self, asyncio.get_running_loop())
        logging.getLogger().addHandler(self._log_handler)
        log.info("rosbridge v2 on ws://%s:%s/", self.host, self.bound_port)

    async def stop(self) -> None:
        if self._log_handler is not None:
            logging.getLogger().removeHandler(self._log_handler)
            self._log_handler = None
        for unsubscribe in self._bus_unsubscribers:
            unsubscribe()
        self._bus_unsubscribers.clear()
        for client in list(self.clients.values()):
            await client.ws.close(code=WSCloseCode.GOING_AWAY, message=b"arbiterd stopping")
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    def health(self) -> dict[str, Any]:
        return {"status": "ok" if self._runner is not None else "error",
                "port": self.bound_port, "clients": len(self.clients),
                "connections": self.connections, "refused": dict(self.refused),
                "dropped_messages": sum(c.outbox.dropped for c in self.clients.values()),
                "protocol_errors": sum(c.errors for c in self.clients.values())}

    # -- admission ----------------------------------------------------------------------------

    async def _handle(self, request: web.Request) -> web.StreamResponse:
        refusal = self._refusal(request)
        if refusal is not None:
            return refusal
        ws = web.WebSocketResponse(max_msg_size=self.max_message_bytes)
        if not ws.can_prepare(request).ok:
            return web.Response(status=426, text="rosbridge v2: connect with a WebSocket\n")
        await ws.prepare(request)
        self.connections += 1
        client_id = self.connections
        peer = request.remote or "?"
        authority = self._authority(request)
        client = self.clients[client_id] = ClientSession(
            ws, client_id, peer, graph=self.graph, control=self.control, authority=authority,
            max_message_bytes=self.max_message_bytes)
        client.transport = request.transport
        log.info("rosbridge client %s connected from %s%s", client_id, peer,
                 "" if authority.may_drive else " (read-only: no valid token)")
        try:
            await client.serve()
        finally:
            del self.clients[client_id]
            await client.close()  # brakes first if it was driving
            log.info("rosbridge client %s disconnected", client_id)
        return ws

    def _authority(self, request: web.Request) -> Authority:
        has_token = self.security.token_ok(request.headers, request.query)
        return Authority(may_read=has_token or not self.security.read_requires_token,
                         may_drive=has_token)

    def _refusal(self, request: web.Request) -> web.Response | None:
        if not self.security.origin_ok(request.headers.get("Origin"), request.host):
            self.refused["origin"] += 1
            return web.Response(status=403, text="rosbridge: Origin not allowed\n")
        if self.security.read_requires_token and not self.security.token_ok(
                request.headers, request.query):
            self.refused["token"] += 1
            return web.Response(status=401, text="rosbridge: a valid token is required\n")
        if len(self.clients) >= self.max_clients:
            self.refused["full"] += 1
            return web.Response(status=503, text=f"rosbridge: {self.max_clients} clients "
                                "already connected\n")
        return None

    # -- telemetry fan-out ------------------------------------------------------------------------

    def _wire_bus(self) -> None:
        for topic in self.graph.topics.values():
            robot = topic.robot
            if robot is not None and robot.direction == "out" and robot.bus:
                self._bus_unsubscribers.append(
                    self.ctx.bus.subscribe(robot.bus, self._bus_callback(topic)))

    def _bus_callback(self, topic: Topic) -> Callable[[Any], None]:
        convert = topic.robot.convert if topic.robot else None

        def on_message(message: Any) -> None:  # runs inside the publisher (control tick)
            if topic.subscribers:
                self.graph.fan_out(topic, SharedMessage(topic.name, message, convert))

        return on_message

    def publish_log(self, record: logging.LogRecord) -> None:
        topic = self.graph.topics.get("/rosout")
        if topic is not None and topic.subscribers:
            self.graph.fan_out(topic, SharedMessage(topic.name, log_msg(record)))


class RosoutHandler(logging.Handler):
    """Copies the daemon's log lines (INFO and up) to /rosout subscribers."""

    def __init__(self, server: RosbridgeServer, loop: asyncio.AbstractEventLoop) -> None:
        super().__init__(logging.INFO)
        self.server = server
        self.loop = loop
        self.thread = threading.get_ident()

    def emit(self, record: logging.LogRecord) -> None:
        try:
            if threading.get_ident() == self.thread:
                self.server.publish_log(record)
            elif not self.loop.is_closed():
                self.loop.call_soon_threadsafe(self.server.publish_log, record)
        except Exception:
            self.handleError(record)
