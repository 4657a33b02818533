# One Foxglove WebSocket client: its subscriptions, its channels, bounded queues and a writer.
from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from aiohttp import WSMsgType, web

from base.rates import TokenBucket
from daemon.components.foxglove import protocol
from daemon.components.foxglove.channels import Channel, Outgoing
from daemon.components.foxglove.protocol import ERROR, WARNING, ProtocolError
from daemon.components.rosbridge.access import TOKEN_HINT, Authority
from daemon.coords import missing_required
from daemon.messages.cdr import CdrError
from daemon.messages.cdr_read import decode as cdr_decode
from daemon.messages.msgtypes import MessageError, check_message, has_type, normalize_type
from daemon.robot import RobotBase
from daemon.topics import Access, Inbound, Refusal, TopicIn

log = logging.getLogger("arbiterd.foxglove")

#: status texts (and parameter replies) kept for a client that is not reading; older go first
TEXT_QUEUE = 256
#: a time frame goes out before a message when the last one is older than this, ns
TIME_EVERY_NS = 100_000_000
#: the same status text again to one client at most this often, s
SAY_AGAIN_S = 2.0
#: publish encodings the server decodes
ENCODINGS = ("cdr", "json")


@dataclass(frozen=True)
class Budget:
    """The ``[foxglove]`` budgets one client works within."""

    frames_per_second: float
    frames_burst: int
    queue_messages: int
    max_subscriptions: int
    max_channels: int


class Hub(Protocol):
    """What a session needs of its server."""

    channels: dict[int, Channel]
    robot: RobotBase

    def incoming(self, name: str) -> TopicIn | None: ...

    def is_outgoing(self, name: str) -> bool: ...

    def watch(self, session: FoxgloveSession, channel: Channel, watched: bool) -> None: ...

    def latest(self, channel: Channel) -> Outgoing | None: ...

    def parameters(self, names: list[str]) -> list[dict[str, Any]]: ...


@dataclass(frozen=True)
class ClientChannel:
    """A channel a client advertised to publish on: the robot's topic when it accepts it."""

    id: int
    topic: str
    type: str
    encoding: str
    robot: TopicIn | None


class FoxgloveSession:
    """Serves one connection (command source ``foxglove:<id>``): reads frames at a bounded
    rate, answers them, and writes messages from bounded queues in a task of its own, so a
    slow reader holds only itself up."""

    def __init__(self, ws: web.WebSocketResponse, client_id: int, peer: str, *, hub: Hub,
                 authority: Authority, budget: Budget,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.ws = ws
        self.id = client_id
        self.peer = peer
        self.hub = hub
        self.authority = authority
        self.budget = budget
        self.clock = clock
        self.source = f"foxglove:{client_id}"
        self.sender = f"foxglove client {client_id} ({peer})"
        self.subscriptions: dict[int, Channel] = {}
        self.advertised: dict[int, ClientChannel] = {}
        self._queues: dict[int, deque[Outgoing]] = {}
        self._ready: dict[int, None] = {}  # subscriptions with a message waiting, in order
        self._texts: deque[str | bytes] = deque(maxlen=TEXT_QUEUE)  # (and the first time)
        self._wake = asyncio.Event()
        self._bucket = TokenBucket(budget.frames_per_second, budget.frames_burst, clock)
        self._said: dict[str, float] = {}
        self._last_time_ns = 0
        self.dropped = 0
        self.errors = 0
        self.throttled = 0
        self.published = 0

    # -- reading ------------------------------------------------------------------------------

    async def serve(self, hello: list[str]) -> None:
        """Greets (``serverInfo``, ``advertise``, then the time: a player that takes the
        server's time has one before any message, which flows only after it subscribed), then
        reads until the socket closes."""
        self._last_time_ns = time.time_ns()
        first: list[str | bytes] = [*hello, protocol.time_frame(self._last_time_ns)]
        self._texts.extend(first)
        self._wake.set()
        writer = asyncio.create_task(self._write_forever(), name=f"foxglove-writer-{self.id}")
        try:
            async for message in self.ws:
                t_recv = self.clock()
                if message.type == WSMsgType.ERROR:
                    log.info("%s: refused frame: %s; closed", self.sender, self.ws.exception())
                    break
                wait = self._bucket.reserve(1.0)
                if wait > 0:  # over the rate: reading pauses (TCP pushes back on the client)
                    self.throttled += 1
                    self.say(WARNING, "too many frames: reading paused ([foxglove] "
                             "frames_per_second)")
                    await asyncio.sleep(wait)
                await self._take(message.type, message.data, t_recv)
                await asyncio.sleep(0)
        finally:
            writer.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await writer

    async def _take(self, kind: WSMsgType, data: Any, t_recv: float) -> None:
        try:
            if kind == WSMsgType.TEXT:
                op, frame = protocol.parse_text(data)
                await getattr(self, f"op_{op}")(frame)
            elif kind == WSMsgType.BINARY:
                await self._publish(protocol.parse_binary(data), t_recv)
        except ProtocolError as exc:
            self.errors += 1
            self.say(ERROR, str(exc))

    # -- subscriptions ------------------------------------------------------------------------

    async def op_subscribe(self, frame: dict[str, Any]) -> None:
        self._need("read", "subscribe")
        for entry in frame["subscriptions"]:
            sub_id = protocol.uint32(protocol.field(entry, "id", "subscribe"), "subscribe: id")
            channel_id = protocol.uint32(protocol.field(entry, "channelId", "subscribe"),
                                         "subscribe: channelId")
            channel = self.hub.channels.get(channel_id)
            if channel is None:
                raise ProtocolError(f"subscribe: no channel {channel_id}")
            if sub_id in self.subscriptions:
                raise ProtocolError(f"subscribe: subscription id {sub_id} is in use")
            if len(self.subscriptions) >= self.budget.max_subscriptions:
                raise ProtocolError(f"subscribe: at most {self.budget.max_subscriptions} "
                                    "subscriptions ([foxglove] max_subscriptions_per_client)")
            self._subscribe(sub_id, channel)

    def _subscribe(self, sub_id: int, channel: Channel) -> None:
        first = channel not in self.subscriptions.values()
        self.subscriptions[sub_id] = channel
        depth = 1 if channel.topic.state else self.budget.queue_messages
        self._queues[sub_id] = deque(maxlen=depth)
        if first:
            self.hub.watch(self, channel, True)
        latest = self.hub.latest(channel) if channel.topic.state else None
        if latest is not None:  # a map published once a while: the new subscriber gets it now
            self._queue(sub_id, latest)
            self._wake.set()

    async def op_unsubscribe(self, frame: dict[str, Any]) -> None:
        for value in frame["subscriptionIds"]:
            sub_id = protocol.uint32(value, "unsubscribe: subscriptionIds[]")
            channel = self.subscriptions.pop(sub_id, None)
            if channel is None:
                raise ProtocolError(f"unsubscribe: no subscription {sub_id}")
            self._queues.pop(sub_id, None)
            self._ready.pop(sub_id, None)
            if channel not in self.subscriptions.values():
                self.hub.watch(self, channel, False)

    def offer(self, message: Outgoing) -> None:
        """A message of a channel this client subscribes to (called by the server in the
        publisher, the control tick: queueing only, no encoding, no I/O)."""
        channel = message.channel
        for sub_id, subscribed in self.subscriptions.items():
            if subscribed is channel:
                self._queue(sub_id, message)
        self._wake.set()

    def _queue(self, sub_id: int, message: Outgoing) -> None:
        queue = self._queues[sub_id]
        if len(queue) == queue.maxlen and not message.channel.topic.state:
            self.dropped += 1  # an event topic's oldest, for a client that does not keep up
        queue.append(message)
        self._ready[sub_id] = None

    # -- client publishing --------------------------------------------------------------------

    async def op_advertise(self, frame: dict[str, Any]) -> None:
        for entry in frame["channels"]:
            channel = self._client_channel(entry)
            if channel.robot is not None:
                self._need(channel.robot.access, f"advertise {channel.topic}")
            else:
                self._need("drive", f"advertise {channel.topic}")
            self.advertised[channel.id] = channel

    def _client_channel(self, entry: Any) -> ClientChannel:
        channel_id = protocol.uint32(protocol.field(entry, "id", "advertise"), "advertise: id")
        topic = protocol.string(protocol.field(entry, "topic", "advertise"), "advertise: topic")
        encoding = protocol.field(entry, "encoding", "advertise")
        if encoding not in ENCODINGS:
            raise ProtocolError(f"advertise {topic}: encoding {str(encoding)[:40]!r} is not "
                                f"one of {', '.join(ENCODINGS)}")
        type_name = self._type(topic, protocol.field(entry, "schemaName", "advertise"))
        if channel_id in self.advertised:
            raise ProtocolError(f"advertise {topic}: channel id {channel_id} is in use")
        if len(self.advertised) >= self.budget.max_channels:
            raise ProtocolError(f"advertise {topic}: at most {self.budget.max_channels} "
                                "channels ([foxglove] max_channels_per_client)")
        if self.hub.is_outgoing(topic):
            raise ProtocolError(f"advertise {topic}: it is published by the robot; clients "
                                "cannot publish to it")
        robot = self.hub.incoming(topic)
        if robot is not None and type_name not in robot.accepted_types():
            raise ProtocolError(f"advertise {topic}: the robot takes "
                                f"{' or '.join(robot.accepted_types())}, not {type_name}")
        return ClientChannel(channel_id, topic, type_name, encoding, robot)

    @staticmethod
    def _type(topic: str, schema_name: Any) -> str:
        try:
            type_name = normalize_type(protocol.string(schema_name, "advertise: schemaName"))
        except MessageError as exc:
            raise ProtocolError(f"advertise {topic}: {exc}") from None
        if not has_type(type_name):
            raise ProtocolError(f"advertise {topic}: unknown message type {schema_name!r}")
        return type_name

    async def op_unadvertise(self, frame: dict[str, Any]) -> None:
        for value in frame["channelIds"]:
            channel = self.advertised.pop(protocol.uint32(value, "unadvertise: channelIds[]"),
                                          None)
            if channel is None:
                raise ProtocolError(f"unadvertise: no channel {value}")
            if channel.robot is not None and channel.robot.moves and not any(
                    c.robot is not None and c.robot.moves for c in self.advertised.values()):
                await self.hub.robot.drop_source(self.source)  # brakes if it was driving

    async def _publish(self, message: protocol.ClientMessage, t_recv: float) -> None:
        channel = self.advertised.get(message.channel_id)
        if channel is None:
            raise ProtocolError(f"message data: channel {message.channel_id} was not "
                                "advertised")
        robot = channel.robot
        if robot is None:
            return  # a topic nobody on the robot takes (the app's /clicked_point)
        self._need(robot.access, f"publish {channel.topic}")  # (checked again: cheap)
        msg = self._decode(channel, message.payload)
        if robot.access_for is not None:  # what this message may do (a release) decides
            self._need(robot.access_for(msg), f"publish {channel.topic}")
        self.published += 1
        refusal = await robot.handler(Inbound(channel.topic, channel.type, msg, self.source,
                                              self.sender, t_recv, self.peer))
        if refusal is not None:
            self._refused(channel.topic, refusal)

    @staticmethod
    def _decode(channel: ClientChannel, payload: bytes) -> dict[str, Any]:
        try:
            if channel.encoding == "cdr":
                value: Any = cdr_decode(channel.type, payload)
            else:
                value = json.loads(payload)
            msg = check_message(channel.type, value)
            missing = None if channel.robot is None else missing_required(
                value, channel.robot.required)  # as sent: before the defaults filled it in
            if missing is not None:
                raise MessageError(f"msg.{missing}")
            return msg
        except (CdrError, MessageError, ValueError, RecursionError) as exc:
            reason = str(exc) or type(exc).__name__
            raise ProtocolError(f"publish {channel.topic}: {reason[:300]}") from None

    def _refused(self, topic: str, refusal: Refusal) -> None:
        message = f"publish {topic}: {refusal.reason}"
        if refusal.repeats:
            self.say(ERROR, message)
        else:
            self.status(ERROR, message)

    def _need(self, access: Access, what: str) -> None:
        if self.authority.allows(access):
            return
        limit = "read-only" if access == "drive" else "not allowed to read telemetry"
        raise ProtocolError(f"{what}: needs a valid token ({TOKEN_HINT}); without it this "
                            f"client is {limit}")

    # -- parameters, and what is not offered --------------------------------------------------

    async def op_getParameters(self, frame: dict[str, Any]) -> None:
        names = [protocol.string(n, "getParameters: parameterNames[]")
                 for n in frame.get("parameterNames", [])]
        reply: dict[str, Any] = {"parameters": self.hub.parameters(names)}
        if "id" in frame:
            reply["id"] = protocol.string(frame["id"], "getParameters: id")
        self.send_text(protocol.text("parameterValues", **reply))

    async def op_setParameters(self, frame: dict[str, Any]) -> None:
        raise ProtocolError("setParameters: the robot's parameters are read-only here (its "
                            "configuration file sets them)")

    async def op_subscribeParameterUpdates(self, frame: dict[str, Any]) -> None:
        return None  # they never change while the daemon runs

    async def op_unsubscribeParameterUpdates(self, frame: dict[str, Any]) -> None:
        return None

    async def op_subscribeConnectionGraph(self, frame: dict[str, Any]) -> None:
        raise ProtocolError("subscribeConnectionGraph: not offered by this server")

    async def op_unsubscribeConnectionGraph(self, frame: dict[str, Any]) -> None:
        return None

    async def op_fetchAsset(self, frame: dict[str, Any]) -> None:
        raise ProtocolError("fetchAsset: not offered by this server")

    # -- writing ------------------------------------------------------------------------------

    def status(self, level: int, message: str) -> None:
        self.send_text(protocol.status(level, message))

    def say(self, level: int, message: str) -> None:
        """A status that may repeat at frame rate: at most every SAY_AGAIN_S per text."""
        now = self.clock()
        if now - self._said.get(message, -1e9) >= SAY_AGAIN_S:
            if len(self._said) > 64:
                self._said.clear()
            self._said[message] = now
            self.status(level, message)

    def send_text(self, text: str) -> None:
        self._texts.append(text)
        self._wake.set()

    async def _write_forever(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            while self._texts or self._ready:
                if self._texts:
                    frame = self._texts.popleft()
                    if isinstance(frame, bytes):
                        await self.ws.send_bytes(frame)
                    else:
                        await self.ws.send_str(frame)
                    continue
                await self._send_next()

    async def _send_next(self) -> None:
        sub_id = next(iter(self._ready))
        del self._ready[sub_id]
        queue = self._queues.get(sub_id)
        if not queue:
            return
        message = queue.popleft()
        if queue:
            self._ready[sub_id] = None  # round robin: the others' turn first
        try:
            payload = message.cdr()
        except CdrError as exc:
            self.say(ERROR, f"{message.channel.topic.name}: {exc}")
            return
        if message.t_ns - self._last_time_ns >= TIME_EVERY_NS:
            self._last_time_ns = message.t_ns
            await self.ws.send_bytes(protocol.time_frame(message.t_ns))
        await self.ws.send_bytes(protocol.message_data(sub_id, message.t_ns, payload))

    async def close(self) -> None:
        """Brake if this client was driving, then forget its subscriptions."""
        await self.hub.robot.drop_source(self.source)
        for channel in set(self.subscriptions.values()):
            self.hub.watch(self, channel, False)
        self.subscriptions.clear()
        self._queues.clear()
        self._ready.clear()
        self.advertised.clear()
