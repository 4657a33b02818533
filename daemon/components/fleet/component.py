# The "fleet" component: the robot in a fleet over Zenoh (telemetry out, operator commands in).
from __future__ import annotations

import asyncio
import json
import logging
import math
import socket
import time
import zlib
from collections import deque
from collections.abc import Callable
from typing import Any

from base.rates import TokenBucket
from daemon.component import BaseComponent, ComponentSpec, DaemonContext
from daemon.components.fleet import keys
from daemon.components.fleet.outbox import Channel, Outbox
from daemon.components.fleet.settings import FleetSettings
from daemon.components.fleet.zconfig import read_secret, robot_config
from daemon.components.recorder.paths import record_directory
from daemon.components.recorder.writer import recordings
from daemon.health import Health
from daemon.messages import cdr
from daemon.messages.cdr_read import decode
from daemon.messages.definitions import LASER_SCAN
from daemon.messages.msgtypes import MessageError, check_message
from daemon.messages.scans import scan_cdr
from daemon.topics import Inbound, TopicIn, TopicOut

log = logging.getLogger("arbiterd.fleet")

SOURCE = "fleet"
#: the largest command payload accepted, bytes
MAX_COMMAND_BYTES = 65536
#: commands per second and topic (a burst of a fifth of it)
MAX_COMMAND_RATE = 50.0
REFUSALS = ("not_allowed", "malformed", "invalid", "refused", "overload")


def available() -> str | None:
    """None when the Zenoh binding imports; else what to install."""
    try:
        import zenoh  # noqa: F401
    except ImportError:
        return "the Zenoh binding is not installed: pip install 'arbiterd[fleet]' (eclipse-zenoh)"
    return None


class FleetMember(BaseComponent):
    """Publishes the robot's telemetry under ``arbiterd/<robot_id>/`` through an
    :class:`Outbox` (the tick only stores the latest message), answers the status, map and
    recordings queryables, and, when the session is authenticated, takes commands as queries
    on ``arbiterd/<robot_id>/cmd/<topic>``: the e-stop always, the rest with
    ``allow_commands``, each through its topic's handler under the source ``fleet``."""

    name = "fleet"
    core = False

    def __init__(self, ctx: DaemonContext, settings: FleetSettings, password: str) -> None:
        self.ctx = ctx
        self.settings = settings
        self.password = password
        self.robot_id = settings.robot_id or _host_id()
        self.authenticated = bool(settings.user and password)
        #: commands are listened to only on an authenticated session (or an opted-out one)
        self.commands_on = self.authenticated or not settings.require_auth
        self.outbox = Outbox()
        self.session: Any = None
        self.connected_once = False
        self.attempts = 0
        self.last_error = ""
        self.received = 0
        self.accepted = 0
        self.refused = dict.fromkeys(REFUSALS, 0)
        self.last_refusal = ""
        self._declared: list[Any] = []
        self._budgets: dict[str, TokenBucket] = {}
        self._tasks: set[asyncio.Task[Any]] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._connector: asyncio.Task[None] | None = None
        self._commands: dict[str, TopicIn] = {}
        #: set once the session is open and publishing
        self.joined = asyncio.Event()

    # -- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._plan_channels()
        self.outbox.start()
        if self.commands_on:
            self._commands = {t.name: t for t in self.ctx.topics.incoming()}
        self._connector = asyncio.create_task(self._connect())

    async def stop(self) -> None:
        if self._connector is not None:
            self._connector.cancel()
        self.outbox.send = None
        await asyncio.to_thread(self.outbox.close)
        for task in list(self._tasks):
            task.cancel()
        await self.ctx.robot.drop_source(SOURCE)
        session, self.session = self.session, None
        if session is not None:
            await asyncio.to_thread(session.close)

    def _plan_channels(self) -> None:
        s = self.settings
        periods = {"odom": 1 / s.pose_rate, "pose": 1 / s.pose_rate,
                   "scan": 1 / s.scan_rate if s.scan_rate else 0.0,
                   "battery_state": 1 / s.battery_rate, "map": s.map_period_s,
                   "diagnostics": 0.0, "rosout": 0.0}
        refresh = {"battery_state": s.refresh_s, "diagnostics": s.refresh_s}
        for name, topic_name in keys.TELEMETRY.items():
            topic = self.ctx.topics.get(topic_name)
            if not isinstance(topic, TopicOut) or (name == "scan" and not s.scan_rate):
                continue
            encode = _encoder(topic)
            encoding = keys.CDR_ENCODING
            if name == "map":
                encode, encoding = _compressed(encode), keys.MAP_ENCODING
            events: deque[Any] | None = deque(maxlen=s.queue) if not topic.state else None
            channel = Channel(keys.topic_key(self.robot_id, topic_name), encoding, encode,
                              periods[name], refresh.get(name, 0.0), events=events)
            feed = self.outbox.add(name, channel)
            if name == "rosout":
                feed = _at_least(logging.getLevelName(s.log_level.upper()), feed)
            self.ctx.plugs.subscribe(topic.bus, feed)
        info = self.outbox.add("info", Channel(keys.robot_key(self.robot_id, keys.INFO),
                                               keys.JSON_ENCODING, _json, 0.0, s.refresh_s))
        info(self._info())

    def _info(self) -> dict[str, Any]:
        return {"robot_id": self.robot_id, "console": self._console_url(),
                "mode": self.ctx.mode, "allow_commands": self.settings.allow_commands,
                "commands": self.commands_on}

    def _console_url(self) -> str:
        if self.settings.console_url:
            return self.settings.console_url
        port = self.ctx.config.sections.get("http", {}).get("port", 8085)
        return f"http://{socket.gethostname()}:{port}/"

    # -- the session ------------------------------------------------------------------------------

    async def _connect(self) -> None:
        """Open the session, trying again every ``retry_s`` until the router answers (once
        open, Zenoh itself reconnects when the router comes back)."""
        config = robot_config(self.settings.router, self.settings.mode, self.settings.user,
                              self.password)
        while self.session is None:
            self.attempts += 1
            try:
                self.session = await asyncio.to_thread(_open, config)
            except Exception as exc:
                if not self.last_error:
                    log.warning("fleet: cannot reach %s (trying again every %g s): %s",
                                self.settings.router or "peers", self.settings.retry_s, exc)
                self.last_error = str(exc)
                await asyncio.sleep(self.settings.retry_s)
        await asyncio.to_thread(self._declare, self.session)
        self.connected_once, self.last_error = True, ""
        self.outbox.send = self._sender(self.session)
        self.joined.set()
        log.info("fleet: robot %s joined through %s (%d channels%s)", self.robot_id,
                 self.settings.router or "peers", len(self.outbox.channels),
                 f", commands: e-stop{' and driving' if self.settings.allow_commands else ''}"
                 if self.commands_on else ", no commands: no credentials")

    def _declare(self, session: Any) -> None:
        rid = self.robot_id
        self._declared.append(session.liveliness().declare_token(
            keys.robot_key(rid, keys.ALIVE)))
        for service in ("status", "map", "recordings"):
            self._declared.append(session.declare_queryable(
                keys.robot_key(rid, keys.SERVICE, service), self._on_query(service)))
        for topic in self._commands.values():
            self._declared.append(session.declare_queryable(
                keys.command_key(rid, topic.name), self._on_command(topic)))

    @staticmethod
    def _sender(session: Any) -> Callable[[str, bytes, str], None]:
        import zenoh

        def send(key: str, payload: bytes, encoding: str) -> None:
            session.put(key, payload, encoding=zenoh.Encoding(encoding),
                        congestion_control=zenoh.CongestionControl.DROP)

        return send

    # -- queryables (Zenoh threads -> the event loop) ---------------------------------------------

    def _to_loop(self, callback: Callable[..., Any], *args: Any) -> None:
        if self._loop is not None and not self._loop.is_closed():
            self._loop.call_soon_threadsafe(callback, *args)

    def _on_query(self, service: str) -> Callable[[Any], None]:
        def on_query(query: Any) -> None:
            self._to_loop(self._answer, service, query)

        return on_query

    def _answer(self, service: str, query: Any) -> None:
        key = keys.robot_key(self.robot_id, keys.SERVICE, service)
        if service == "status":
            query.reply(key, _json(self.status()), encoding=_encoding(keys.JSON_ENCODING))
        elif service == "recordings":
            self._spawn(self._answer_recordings(key, query))
        else:
            channel = self.outbox.channels.get("map")
            if channel is None or not channel.has_latest:
                query.reply_err(b"no map yet")
                return
            query.reply(key, channel.encode(channel.latest),
                        encoding=_encoding(keys.MAP_ENCODING))

    async def _answer_recordings(self, key: str, query: Any) -> None:
        directory = record_directory(self.ctx.config.sections.get("recorder", {}))
        files = await asyncio.to_thread(_listing, directory)
        query.reply(key, _json({"recordings": files}), encoding=_encoding(keys.JSON_ENCODING))

    def status(self) -> dict[str, Any]:
        robot = self.ctx.robot
        x, y, theta = robot.pose_xyt()
        return {"robot_id": self.robot_id, "health": self.ctx.reports.health()["status"],
                "estop_engaged": robot.estop_engaged, "estop_reason": robot.estop_reason,
                "fault": robot.fault, "pose": {"x": x, "y": y, "theta": theta},
                "safety_action": robot.safety_action(), "console": self._console_url()}

    # -- commands ---------------------------------------------------------------------------------

    def _on_command(self, topic: TopicIn) -> Callable[[Any], None]:
        def on_query(query: Any) -> None:  # a Zenoh thread
            self._to_loop(self._command, topic, query, time.monotonic())

        return on_query

    def _command(self, topic: TopicIn, query: Any, t_recv: float) -> None:
        self.received += 1
        payload = query.payload
        data = payload.to_bytes() if payload is not None else b""
        if not self._budget(topic).take():
            self._refuse(query, "overload", f"{topic.name}: over {MAX_COMMAND_RATE:g} a second")
            return
        if len(data) > MAX_COMMAND_BYTES:
            self._refuse(query, "malformed", f"{topic.name}: over {MAX_COMMAND_BYTES} bytes")
            return
        try:
            msg = check_message(topic.type, decode(topic.type, data))
        except (cdr.CdrError, MessageError) as exc:
            self._refuse(query, "malformed", f"{topic.name}: {exc}")
            return
        need = topic.access_for(msg) if topic.access_for is not None else topic.access
        if need not in ("open", "stop") and not self.settings.allow_commands:
            self._refuse(query, "not_allowed", f"{topic.name}: commands from the fleet are off "
                         "([fleet] allow_commands = false)")
            return
        self._spawn(self._deliver(topic, msg, t_recv, query))

    async def _deliver(self, topic: TopicIn, msg: dict[str, Any], t_recv: float,
                       query: Any) -> None:
        timeout = self.settings.command_timeout or None
        refusal = await topic.handler(Inbound(
            topic.name, topic.type, msg, SOURCE, "the fleet operator", t_recv, "zenoh",
            self.settings.command_priority, timeout))
        if refusal is not None:
            self._refuse(query, "refused" if refusal.repeats else "invalid",
                         f"{topic.name}: {refusal.reason}")
            return
        self.accepted += 1
        query.reply(keys.command_key(self.robot_id, topic.name),
                    _json({"robot_id": self.robot_id, "accepted": True}),
                    encoding=_encoding(keys.JSON_ENCODING))

    def _refuse(self, query: Any, kind: str, reason: str) -> None:
        self.refused[kind] += 1
        self.last_refusal = reason
        query.reply_err(_json({"robot_id": self.robot_id, "accepted": False,
                               "error": reason}))

    def _budget(self, topic: TopicIn) -> TokenBucket:
        budget = self._budgets.get(topic.name)
        if budget is None:
            budget = self._budgets[topic.name] = TokenBucket(
                MAX_COMMAND_RATE, MAX_COMMAND_RATE / 5, time.monotonic)
        return budget

    def _spawn(self, coro: Any) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    # -- health ---------------------------------------------------------------------------------

    def connected(self) -> bool:
        session = self.session
        if session is None:
            return False
        try:
            return bool(list(session.info.routers_zid()) or list(session.info.peers_zid()))
        except Exception:
            return False

    def health(self) -> Health:
        values = self._figures()
        if self.session is None:
            return Health("degraded", f"not in the fleet: cannot reach "
                          f"{self.settings.router or 'peers'}: {self.last_error}"[:300], values)
        if not values["connected"]:
            return Health("degraded", "lost the fleet router; reconnecting", values)
        return Health("ok", values=values)

    def _figures(self) -> dict[str, Any]:
        return {"robot_id": self.robot_id, "router": self.settings.router,
                "connected": self.connected(), "attempts": self.attempts,
                "commands": "e-stop and driving" if self.commands_on and
                self.settings.allow_commands else "e-stop" if self.commands_on else "none",
                "sent": {name: c.sent for name, c in self.outbox.channels.items()},
                "sent_bytes": sum(c.sent_bytes for c in self.outbox.channels.values()),
                "dropped": self.outbox.dropped, "received": self.received,
                "accepted": self.accepted, "refused": dict(self.refused),
                "last_refusal": self.last_refusal}


def _open(config: dict[str, Any]) -> Any:
    import zenoh

    return zenoh.open(zenoh.Config.from_json5(json.dumps(config)))


def _encoding(name: str) -> Any:
    import zenoh

    return zenoh.Encoding(name)


def _host_id() -> str:
    name = "".join(c if c.isalnum() or c in "_-" else "-" for c in socket.gethostname())
    return name[:64] or "robot"


def _json(value: Any) -> bytes:
    return json.dumps(value, default=_finite).encode()


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return str(value)


def _encoder(topic: TopicOut[Any]) -> Callable[[Any], bytes]:
    if topic.type == LASER_SCAN:
        return scan_cdr
    convert, type_name = topic.convert, topic.type
    return lambda message: cdr.encode(type_name, convert(message))


def _compressed(encode: Callable[[Any], bytes]) -> Callable[[Any], bytes]:
    return lambda message: zlib.compress(encode(message), 6)


def _at_least(level: int, feed: Callable[[Any], None]) -> Callable[[logging.LogRecord], None]:
    def on_record(record: logging.LogRecord) -> None:
        if record.levelno >= level:
            feed(record)

    return on_record


def _listing(directory: Any) -> list[dict[str, Any]]:
    out = []
    for path in recordings(directory):
        try:
            out.append({"name": path.name, "bytes": path.stat().st_size})
        except OSError:
            continue
    return out


def create(ctx: DaemonContext) -> FleetMember | None:
    """Component factory; None unless ``[fleet] enabled``. Enabled without the Zenoh binding,
    or allowing commands without credentials, is a configuration error that says why."""
    settings = ctx.settings(FleetSettings)
    if not settings.enabled:
        return None
    missing = available()
    if missing is not None:
        raise ValueError(f"[fleet] enabled = true, but {missing}")
    password = read_secret(settings.password, settings.password_file)
    if settings.allow_commands and settings.require_auth and not (settings.user and password):
        raise ValueError("[fleet] allow_commands = true needs user and password (or "
                         "password_file): no anonymous driving (require_auth = false only on "
                         "a closed network)")
    if settings.mode == "client" and not settings.router:
        raise ValueError("[fleet] enabled = true needs router = \"tcp/HOST:PORT\" (the "
                         "address `arbiterd fleet` listens on), or mode = \"peer\"")
    return FleetMember(ctx, settings, password)


COMPONENT = ComponentSpec("fleet", create, FleetSettings)
