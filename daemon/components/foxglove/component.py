# The Foxglove WebSocket component (:8765): admission as rosbridge's, and the topic table's
# outgoing topics as channels over the bus.
from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable
from typing import Any

from aiohttp import HttpVersion10, WSCloseCode, web

from base.config import Config
from daemon.component import BaseComponent, ComponentSpec, DaemonContext
from daemon.components.foxglove import protocol
from daemon.components.foxglove.channels import Channel, Outgoing, channels
from daemon.components.foxglove.session import Budget, FoxgloveSession
from daemon.components.foxglove.settings import FoxgloveSettings
from daemon.components.http.conn import CappedRunner
from daemon.components.rosbridge.access import Authority
from daemon.components.rosbridge.maskgate import MaskGate
from daemon.health import Health
from daemon.listen import Listener, start_listening
from daemon.topics import TopicIn

log = logging.getLogger("arbiterd.foxglove")

#: on stop: how long the clients get to take their close frames
SHUTDOWN_GRACE_S = 1.0
#: the configuration sections offered as read-only parameters (``section.key``)
PARAMETER_SECTIONS = ("robot", "control", "limits", "collision_monitor", "navigation")
#: the distro the app is told when the DDS face does not say (its message definitions)
DEFAULT_DISTRO = "jazzy"


def create(ctx: DaemonContext) -> FoxgloveServer | None:
    """Component factory; None unless ``[foxglove] enabled``."""
    if not ctx.settings(FoxgloveSettings).enabled:
        return None
    return FoxgloveServer(ctx)


class FoxgloveServer(BaseComponent):
    """Serves the Foxglove WebSocket protocol on ``ws://host:port/``: every outgoing topic
    of the topic table as a channel (ros2msg schema, CDR messages), client publishing to the
    robot's incoming topics under the same token, Host and Origin rules as rosbridge, the
    robot's configuration as read-only parameters, and the server's time."""

    name = "foxglove"
    core = False

    def __init__(self, ctx: DaemonContext) -> None:
        cfg = ctx.settings(FoxgloveSettings)
        self.ctx = ctx
        self.robot = ctx.robot
        self.security = ctx.security
        self.cfg = cfg
        self.budget = Budget(cfg.frames_per_second, cfg.frames_burst, cfg.queue_messages,
                             cfg.max_subscriptions_per_client, cfg.max_channels_per_client)
        self.channels: dict[int, Channel] = {}
        self.clients: dict[int, FoxgloveSession] = {}
        self.refused = {"http09": 0, "host": 0, "origin": 0, "token": 0, "guessing": 0,
                        "full": 0, "subprotocol": 0}
        self.connections = 0
        self.bound_port: int | None = None
        self._hello: list[str] = []
        self._runner: CappedRunner | None = None
        #: per channel id: the sessions subscribed, and the bus subscription feeding them
        self._watchers: dict[int, set[FoxgloveSession]] = {}
        self._bus_unsubscribers: dict[int, Callable[[], None]] = {}
        self._parameters: dict[str, Any] = {}

    # -- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> None:
        self.channels = channels(self.ctx.topics.outgoing())
        self._parameters = _parameters(self.ctx.config)
        self._hello = self._greeting()
        app = web.Application()
        app.router.add_get("/", self._handle)
        self._runner = CappedRunner(app, self.cfg.max_connections, label="foxglove",
                                    setting="[foxglove] max_connections", access_log=None,
                                    handle_signals=False,
                                    keepalive_timeout=self.cfg.handshake_timeout_s,
                                    shutdown_timeout=SHUTDOWN_GRACE_S)
        try:
            self.bound_port = await start_listening(
                self._runner, Listener("foxglove", self.cfg.host, self.cfg.port))
        except OSError:
            self._runner = None
            raise
        log.info("Foxglove WebSocket on ws://%s:%s/ (%d channels)", self.cfg.host,
                 self.bound_port, len(self.channels))

    def _greeting(self) -> list[str]:
        distro = self.ctx.config.sections.get("ros2", {}).get("distro", DEFAULT_DISTRO)
        info = protocol.text(
            "serverInfo", name="arbiterd",
            capabilities=["clientPublish", "parameters", "time"],
            supportedEncodings=["cdr", "json"],
            metadata={"ROS_DISTRO": distro}, sessionId=str(time.time_ns()))
        advertise = protocol.text("advertise", channels=[
            channel.advertisement() for channel in self.channels.values()])
        return [info, advertise]

    async def stop(self) -> None:
        for unsubscribe in self._bus_unsubscribers.values():
            unsubscribe()
        self._bus_unsubscribers.clear()
        self._watchers.clear()
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
        values = {
            "port": self.bound_port, "clients": len(self.clients),
            "connections": self.connections, "refused": dict(self.refused),
            "channels": len(self.channels),
            "subscribed_channels": len(self._bus_unsubscribers),
            "dropped_messages": sum(c.dropped for c in self.clients.values()),
            "throttled_frames": sum(c.throttled for c in self.clients.values()),
            "protocol_errors": sum(c.errors for c in self.clients.values()),
            "published": sum(c.published for c in self.clients.values())}
        if self._runner is None:
            return Health("error", "not listening", values)
        return Health("ok", values=values)

    # -- the hub its sessions use -------------------------------------------------------------

    def incoming(self, name: str) -> TopicIn | None:
        topic = self.ctx.topics.get(name)
        return topic if isinstance(topic, TopicIn) else None

    def is_outgoing(self, name: str) -> bool:
        topic = self.ctx.topics.get(name)
        return topic is not None and not isinstance(topic, TopicIn)

    def watch(self, session: FoxgloveSession, channel: Channel, watched: bool) -> None:
        """Listen to a channel's bus key only while a client subscribes to it: a topic nobody
        watches costs its publisher (the control tick) nothing here."""
        sessions = self._watchers.setdefault(channel.id, set())
        if watched:
            sessions.add(session)
            if channel.id not in self._bus_unsubscribers:
                self._bus_unsubscribers[channel.id] = self.ctx.bus.subscribe(
                    channel.topic.bus, self._bus_callback(channel, sessions))
        else:
            sessions.discard(session)
            if not sessions and channel.id in self._bus_unsubscribers:
                self._bus_unsubscribers.pop(channel.id)()

    @staticmethod
    def _bus_callback(channel: Channel,
                      sessions: set[FoxgloveSession]) -> Callable[[Any], None]:
        def on_message(message: Any) -> None:  # runs inside the publisher (control tick)
            if sessions:
                shared = Outgoing(channel, message)
                for session in sessions:
                    session.offer(shared)

        return on_message

    def latest(self, channel: Channel) -> Outgoing | None:
        message = self.ctx.bus.latest(channel.topic.bus)
        return None if message is None else Outgoing(channel, message)

    def parameters(self, names: list[str]) -> list[dict[str, Any]]:
        wanted = names or list(self._parameters)
        return [{"name": name, "value": self._parameters[name]} for name in wanted
                if name in self._parameters]

    # -- admission ----------------------------------------------------------------------------

    async def _handle(self, request: web.Request) -> web.StreamResponse:
        if request.version < HttpVersion10:
            http09 = self._refuse("http09", 400, "HTTP/0.9 is not supported")
            http09.force_close()
            return http09
        if self.security.guessing(request.headers, request.query, request.remote):
            return self._refuse("guessing", 429, "too many wrong tokens from this address; "
                                "wait a second")
        has_token = self.security.token_ok(request.headers, request.query, request.remote)
        refusal = self._refusal(request, has_token)
        if refusal is not None:
            return refusal
        authority = Authority(may_read=has_token or not self.security.read_requires_token,
                              may_drive=has_token,
                              proved=has_token and self.security.token_required)
        limit = self.cfg.max_message_bytes if authority.may_drive else min(
            self.cfg.max_message_bytes, self.cfg.max_readonly_message_bytes)
        ws = web.WebSocketResponse(protocols=protocol.SUBPROTOCOLS, max_msg_size=limit)
        if not ws.can_prepare(request).ok:
            return web.Response(status=426, text="foxglove: connect with a WebSocket\n")
        _refuse_unmasked(request, ws)
        await ws.prepare(request)
        self.connections += 1
        client_id = self.connections
        peer = request.remote or "?"
        session = self.clients[client_id] = FoxgloveSession(
            ws, client_id, peer, hub=self, authority=authority, budget=self.budget)
        log.info("foxglove client %d connected from %s (%s)%s", client_id, peer, ws.ws_protocol,
                 "" if authority.may_drive else " (read-only: no valid token)")
        try:
            await session.serve(self._hello)
        finally:
            del self.clients[client_id]
            await session.close()  # brakes first if it was driving
            log.info("foxglove client %d disconnected", client_id)
        return ws

    def _refusal(self, request: web.Request, has_token: bool) -> web.Response | None:
        host = request.headers.get("Host")
        if not self.security.host_ok(host):
            return self._refuse("host", 403, "Host not allowed; add it to [security] "
                                "allowed_hosts if this is the robot's name")
        if not self.security.origin_ok(request.headers.get("Origin"), host):
            return self._refuse("origin", 403, "Origin not allowed")
        if self.security.read_requires_token and not has_token:
            return self._refuse("token", 401, "a valid token is required")
        offered = [p.strip() for p in request.headers.get("Sec-WebSocket-Protocol", "")
                   .split(",")]
        if not set(offered) & set(protocol.SUBPROTOCOLS):
            return self._refuse("subprotocol", 400, "offer the WebSocket subprotocol "
                                + " or ".join(protocol.SUBPROTOCOLS))
        if len(self.clients) >= self.cfg.max_clients:
            return self._refuse("full", 503, f"{self.cfg.max_clients} clients already "
                                "connected")
        if self.security.token_required and not has_token and self._tokenless_full():
            return self._refuse("full", 503, "the slots open to clients without the token are "
                                f"taken ([foxglove] reserved_clients = "
                                f"{self.cfg.reserved_clients} are kept for clients with it)")
        return None

    def _tokenless_full(self) -> bool:
        tokenless = sum(1 for c in self.clients.values() if not c.authority.proved)
        return tokenless >= self.cfg.max_clients - self.cfg.reserved_clients

    def _refuse(self, reason: str, status: int, text: str) -> web.Response:
        self.refused[reason] += 1
        return web.Response(status=status, text=f"foxglove: {text}\n")


def _parameters(config: Config) -> dict[str, Any]:
    """The robot's configuration as parameters: scalar keys of a few sections (never
    ``[security]``), named ``section.key``."""
    params: dict[str, Any] = {}
    for section in PARAMETER_SECTIONS:
        for key, value in config.sections.get(section, {}).items():
            if isinstance(value, (bool, int, str)) or (isinstance(value, float)
                                                        and math.isfinite(value)):
                params[f"{section}.{key}"] = value
    return params


def _refuse_unmasked(request: web.Request, ws: web.WebSocketResponse) -> None:
    """A :class:`MaskGate` in front of the frame parser aiohttp installs at the upgrade: an
    unmasked client frame closes the connection (RFC 6455 5.1), as on rosbridge."""
    proto: Any = request.protocol
    install = proto.set_parser

    def set_parser(parser: Any, data_received_cb: Any = None) -> None:
        install(MaskGate(parser, lambda exc: ws._reader.set_exception(exc)),  # type: ignore
                data_received_cb)

    proto.set_parser = set_parser


def listens(config: Config) -> list[Listener]:
    cfg = config.get(FoxgloveSettings)
    return [Listener("foxglove", cfg.host, cfg.port)] if cfg.enabled else []


COMPONENT = ComponentSpec("foxglove", create, FoxgloveSettings, listens=listens)
