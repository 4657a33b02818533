# The rosbridge v2 WebSocket component (:9090): admission, and the topic table over the bus.
from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from typing import Any

from aiohttp import HttpVersion10, WSCloseCode, web

from base.config import Config
from daemon.component import BaseComponent, ComponentSpec, DaemonContext
from daemon.components.http.conn import CappedRunner
from daemon.components.rosbridge.access import Authority
from daemon.components.rosbridge.graph import BridgeGraph, Topic
from daemon.components.rosbridge.limits import Limits, Pacer, RateLimitedLog
from daemon.components.rosbridge.maskgate import MaskGate
from daemon.components.rosbridge.outbox import SharedMessage
from daemon.components.rosbridge.session import ClientSession
from daemon.components.rosbridge.settings import RosbridgeSettings
from daemon.health import Health
from daemon.listen import Listener, start_listening
from daemon.topics import TopicOut

log = logging.getLogger("arbiterd.rosbridge")

#: on stop: how long the clients get to take their close frames, and a handler to end
SHUTDOWN_GRACE_S = 1.0


def create(ctx: DaemonContext) -> RosbridgeServer | None:
    """Component factory; None when ``[rosbridge] enabled = false``."""
    if not ctx.settings(RosbridgeSettings).enabled:
        return None
    return RosbridgeServer(ctx)


class RosbridgeServer(BaseComponent):
    """Serves rosbridge v2 on ``ws://host:port/``: the topic table's bridged topics (robot
    topics out from the bus, incoming ones to their handlers) and clients' own topics and
    services."""

    name = "rosbridge"
    core = False

    def __init__(self, ctx: DaemonContext) -> None:
        cfg = ctx.settings(RosbridgeSettings)
        self.ctx = ctx
        self.robot = ctx.robot
        self.security = ctx.security
        self.host: str = cfg.host
        self.port: int = cfg.port
        self.max_clients: int = cfg.max_clients
        self.max_connections: int = cfg.max_connections
        self.handshake_timeout_s: float = cfg.handshake_timeout_s
        self.reserved_clients: int = cfg.reserved_clients
        self.idle_timeout: float = cfg.idle_timeout
        self.limits = Limits.from_settings(cfg)
        #: the robot's topics join when it starts (every component has declared its own)
        self.graph = BridgeGraph((), latest=ctx.bus.latest)
        self.clients: dict[int, ClientSession] = {}
        self.refused = {"http09": 0, "host": 0, "origin": 0, "token": 0, "guessing": 0, "full": 0,
                        "idle": 0}
        self.connections = 0
        self.bound_port: int | None = None
        self.bad_input = RateLimitedLog(log, interval_s=10.0)
        self.pacer = Pacer(self.limits.fragments_per_second)
        self._conn_log = RateLimitedLog(log, interval_s=1.0)
        self._runner: CappedRunner | None = None
        self._sweeper: asyncio.Task[None] | None = None
        #: set when a client without the token's proof connects: the idle sweeper sleeps without
        self._unproved = asyncio.Event()
        #: the bus subscriptions of the robot topics clients watch now, by topic name
        self._bus_unsubscribers: dict[str, Callable[[], None]] = {}
        #: bulk messages waiting for the next control tick, and its timer
        self._bulk: list[tuple[Topic, SharedMessage]] = []
        self._bulk_handle: asyncio.Handle | None = None

    # -- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> None:
        self.graph = BridgeGraph(self.ctx.topics.bridged(), latest=self.ctx.bus.latest)
        app = web.Application()
        app.router.add_get("/", self._handle)
        # every TCP connection counts, upgraded or not: over the cap the oldest one still
        # without a complete upgrade request goes, and one that sends none in time too
        self._runner = CappedRunner(app, self.max_connections, label="rosbridge",
                                    setting="[rosbridge] max_connections", access_log=None,
                                    handle_signals=False,
                                    keepalive_timeout=self.handshake_timeout_s,
                                    shutdown_timeout=SHUTDOWN_GRACE_S)
        try:
            self.bound_port = await start_listening(
                self._runner, Listener("rosbridge", self.host, self.port))
        except OSError:
            self._runner = None
            raise
        self._wire_bus()
        if self.idle_timeout > 0:
            self._sweeper = asyncio.create_task(self._close_idle_forever(),
                                                name="rosbridge-idle")
        log.info("rosbridge v2 on ws://%s:%s/", self.host, self.bound_port)

    async def stop(self) -> None:
        if self._sweeper is not None:
            self._sweeper.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._sweeper
            self._sweeper = None
        self.graph.on_watch = lambda topic, watched: None
        for unsubscribe in self._bus_unsubscribers.values():
            unsubscribe()
        self._bus_unsubscribers.clear()
        if self._bulk_handle is not None:
            self._bulk_handle.cancel()
            self._bulk_handle, self._bulk = None, []
        closing = [asyncio.create_task(client.ws.close(code=WSCloseCode.GOING_AWAY,
                                                       message=b"arbiterd stopping"))
                   for client in list(self.clients.values())]
        if closing:  # a client that reads nothing does not hold the others (or the daemon)
            _, late = await asyncio.wait(closing, timeout=SHUTDOWN_GRACE_S)
            for task in late:
                task.cancel()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    def health(self) -> Health:
        server = self._runner.server if self._runner is not None else None
        values = {
            "port": self.bound_port, "clients": len(self.clients),
            "open_connections": len(server.connections) if server else 0,
            "connections_closed_at_cap": getattr(server, "refused", 0),
            "connections": self.connections, "refused": dict(self.refused),
            "dropped_messages": sum(c.outbox.dropped for c in self.clients.values()),
            "throttled_requests": sum(c.over_rate for c in self.clients.values()),
            "protocol_errors": sum(c.errors for c in self.clients.values()),
            "pending_calls": len(self.graph.pending)}
        if self._runner is None:
            return Health("error", "not listening", values)
        return Health("ok", values=values)

    # -- admission ----------------------------------------------------------------------------

    async def _handle(self, request: web.Request) -> web.StreamResponse:
        if request.version < HttpVersion10:  # no headers, no Host: nothing to check;
            http09 = self._refuse("http09", 400, "HTTP/0.9 is not supported: connect with a "
                                  "WebSocket (HTTP/1.1)")  # refused, as on the HTTP port,
            http09.force_close()  # and the connection closed
            return http09
        token = self.security.check_token(request.headers, request.query, request.remote)
        if token == "guessing":
            return self._refuse("guessing", 429, "too many wrong tokens from this address; "
                                "wait a second")
        has_token = token == "ok"
        refusal = self._refusal(request, has_token)
        if refusal is not None:
            return refusal
        authority = self._authority(has_token)
        # a client that may not publish is held to small frames before any is parsed
        ws = web.WebSocketResponse(
            max_msg_size=self.limits.message_bytes(authority.may_drive))
        if not ws.can_prepare(request).ok:
            return web.Response(status=426, text="rosbridge v2: connect with a WebSocket\n")
        _refuse_unmasked(request, ws)
        await ws.prepare(request)
        self.connections += 1
        client_id = self.connections
        peer = request.remote or "?"
        client = self.clients[client_id] = ClientSession(
            ws, client_id, peer, graph=self.graph, control=self.robot, authority=authority,
            limits=self.limits, bad_input=self.bad_input, pacer=self.pacer)
        client.transport = request.transport
        if not authority.proved:
            self._unproved.set()
        self._conn_log(logging.INFO, f"rosbridge client {client_id} connected from {peer}"
                       + ("" if authority.may_drive else " (read-only: no valid token)"))
        try:
            await client.serve()
        finally:
            del self.clients[client_id]
            await client.close()  # brakes first if it was driving
            self._conn_log(logging.INFO, f"rosbridge client {client_id} disconnected")
        return ws

    def _authority(self, has_token: bool) -> Authority:
        return Authority(may_read=has_token or not self.security.read_requires_token,
                         may_drive=has_token,
                         proved=has_token and self.security.token_required)

    def _refusal(self, request: web.Request, has_token: bool) -> web.Response | None:
        host = request.headers.get("Host")
        if not self.security.host_ok(host):
            return self._refuse("host", 403, "Host not allowed; add it to [security] "
                                "allowed_hosts if this is the robot's name")
        if not self.security.origin_ok(request.headers.get("Origin"), host):
            return self._refuse("origin", 403, "Origin not allowed")
        if self.security.read_requires_token and not has_token:
            return self._refuse("token", 401, "a valid token is required")
        if len(self.clients) >= self.max_clients:
            return self._refuse("full", 503, f"{self.max_clients} clients already connected")
        if self.security.token_required and not has_token and self._tokenless_full():
            return self._refuse("full", 503, f"the slots open to clients without the token are "
                                f"taken ([rosbridge] reserved_clients = "
                                f"{self.reserved_clients} are kept for clients with it)")
        return None

    def _refuse(self, reason: str, status: int, text: str) -> web.Response:
        self.refused[reason] += 1
        return web.Response(status=status, text=f"rosbridge: {text}\n")

    def _tokenless_full(self) -> bool:
        tokenless = sum(1 for c in self.clients.values() if not c.authority.proved)
        return tokenless >= self.max_clients - self.reserved_clients

    async def _close_idle_forever(self) -> None:
        """Connections without the token that hold nothing and say nothing are closed. The
        sweeps come with a control tick, and none while no such client is connected."""
        while True:
            if all(client.authority.proved for client in self.clients.values()):
                self._unproved.clear()
                await self._unproved.wait()
            await self.robot.sleep_to_tick(min(1.0, self.idle_timeout / 4))
            now = time.monotonic()
            for client in list(self.clients.values()):
                since = client.idle_since()
                if not client.authority.proved and since is not None \
                        and now - since > self.idle_timeout:
                    self.refused["idle"] += 1
                    await client.ws.close(code=WSCloseCode.POLICY_VIOLATION,
                                          message=b"idle without a token ([rosbridge] "
                                          b"idle_timeout)")

    # -- telemetry fan-out ------------------------------------------------------------------------

    def _wire_bus(self) -> None:
        """Listen to a robot topic's bus key only while a client subscribes to it: a topic
        nobody watches costs its publisher (the control tick, every command) nothing here."""
        self.graph.on_watch = self._watch

    def _watch(self, topic: Topic, watched: bool) -> None:
        robot = topic.robot
        if not isinstance(robot, TopicOut):
            return
        if watched and topic.name not in self._bus_unsubscribers:
            self._bus_unsubscribers[topic.name] = self.ctx.bus.subscribe(
                robot.bus, self._bus_callback(topic, robot))
        elif not watched and topic.name in self._bus_unsubscribers:
            self._bus_unsubscribers.pop(topic.name)()

    def _bus_callback(self, topic: Topic, robot: TopicOut[Any]) -> Callable[[Any], None]:
        convert, fan_out = robot.convert, self.graph.fan_out
        if robot.bulk:
            fan_out = self._fan_out_after_tick

        def on_message(message: Any) -> None:  # runs inside the publisher (control tick)
            if topic.subscribers:
                fan_out(topic, SharedMessage(topic.name, message, convert))

        return on_message

    def _fan_out_after_tick(self, topic: Topic, shared: SharedMessage) -> None:
        """A bulk message (a scan, a map) goes to its subscribers right after the next control
        tick: its encoding and sends then never hold a tick up."""
        self._bulk.append((topic, shared))
        if self._bulk_handle is None:
            self._bulk_handle = self.robot.call_after_tick(self._send_bulk)

    def _send_bulk(self) -> None:
        self._bulk_handle = None
        waiting, self._bulk = self._bulk, []
        for topic, message in waiting:
            if topic.subscribers:
                self.graph.fan_out(topic, message)


def _refuse_unmasked(request: web.Request, ws: web.WebSocketResponse) -> None:
    """Put a :class:`MaskGate` in front of the frame parser aiohttp installs at the upgrade
    (before any frame, even one sent along with the upgrade request, reaches it)."""
    protocol: Any = request.protocol
    install = protocol.set_parser

    def set_parser(parser: Any, data_received_cb: Any = None) -> None:
        install(MaskGate(parser, lambda exc: ws._reader.set_exception(exc)),  # type: ignore
                data_received_cb)

    protocol.set_parser = set_parser


def listens(config: Config) -> list[Listener]:
    bridge = config.get(RosbridgeSettings)
    return [Listener("rosbridge", bridge.host, bridge.port)] if bridge.enabled else []


COMPONENT = ComponentSpec("rosbridge", create, RosbridgeSettings, listens=listens)
