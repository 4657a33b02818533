# One WebSocket client: reads ops, drives the robot, and writes its queued replies and topics.
from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

import orjson
from aiohttp import WSMsgType, web

from daemon.control.api import STAMP_FIELDS, parse_stamp
from daemon.control.commands import CommandError, parse_twist
from daemon.rosbridge import rosapi
from daemon.rosbridge.codec import (
    STATUS_LEVELS,
    Defragmenter,
    Id,
    ProtocolError,
    decode_frame,
    encode,
    fragments,
    get_bool,
    get_int,
    get_number,
    get_str,
    level_allows,
    request_id,
    status_frame,
    topic_name,
)
from daemon.rosbridge.graph import PendingCall, ProvidedService, Topic
from daemon.rosbridge.msgtypes import MessageError, check_message, has_type, normalize_type
from daemon.rosbridge.outbox import Outbox, SharedMessage, SubscribeOptions, TopicQueue
from daemon.rosbridge.topics import COMMAND_TOPICS, TWIST, TWIST_STAMPED

if TYPE_CHECKING:
    from daemon.rosbridge.server import RosbridgeServer

log = logging.getLogger("arbiterd.rosbridge")

COMPRESSIONS = ("none", "png", "cbor", "cbor-raw")
INLINE_SENDS = 4  # most messages the reader sends itself after one request
REFUSAL_REPEAT_S = 0.5  # the same refused-command status at most this often per client

OpHandler = Callable[[dict[str, Any], float], Awaitable[None]]


class ClientSession:
    """State and op handlers of one connected client (command source ``ws:<id>``)."""

    def __init__(self, server: RosbridgeServer, ws: web.WebSocketResponse, client_id: int,
                 may_drive: bool, peer: str) -> None:
        self.server = server
        self.ws = ws
        self.id = client_id
        self.source = f"ws:{client_id}"
        self.may_drive = may_drive
        self.peer = peer
        self.transport: asyncio.BaseTransport | None = None
        self.level = "error"
        self.advertised: dict[str, set[Id]] = {}
        self.latching: set[str] = set()
        self.outbox = Outbox(self._wake)
        self.defrag = Defragmenter(server.max_message_bytes)
        self.frames_in = 0
        self.errors = 0
        self._wakeup = asyncio.Event()
        self._writer_idle = False
        self._next_delay: float | None = None
        self._refusals: dict[str, float] = {}
        self._ops: dict[str, OpHandler] = {
            "advertise": self.op_advertise, "unadvertise": self.op_unadvertise,
            "publish": self.op_publish, "subscribe": self.op_subscribe,
            "unsubscribe": self.op_unsubscribe, "call_service": self.op_call_service,
            "service_response": self.op_service_response,
            "advertise_service": self.op_advertise_service,
            "unadvertise_service": self.op_unadvertise_service,
            "set_level": self.op_set_level, "fragment": self.op_fragment,
        }

    def __repr__(self) -> str:
        return f"<client {self.id} {self.peer}>"

    # -- reading ----------------------------------------------------------------------------

    async def serve(self) -> None:
        """Read frames until the socket closes; the writer runs beside it."""
        writer = asyncio.create_task(self._write_forever(), name=f"rosbridge-writer-{self.id}")
        try:
            async for message in self.ws:
                t_recv = time.monotonic()
                if message.type in (WSMsgType.TEXT, WSMsgType.BINARY):
                    await self.handle_text(message.data, t_recv)
                    if self._writer_idle:
                        await self._send_inline()
                elif message.type == WSMsgType.ERROR:
                    log.info("client %s: socket error: %s", self.id, self.ws.exception())
                    break
        finally:
            writer.cancel()

    async def handle_text(self, text: str | bytes, t_recv: float, nested: bool = False) -> None:
        self.frames_in += 1
        try:
            frame = decode_frame(text)
            handler = self._ops.get(frame["op"])
            if handler is None or (nested and frame["op"] == "fragment"):
                raise ProtocolError(f"unknown operation {frame['op']!r}; allowed operations: "
                                    f"{', '.join(self._ops)}", request_id(frame))
            await handler(frame, t_recv)
        except ProtocolError as exc:
            self.errors += 1
            self.status("error", exc.message, exc.request_id)
        except Exception:
            log.exception("client %s: request failed", self.id)
            self.errors += 1
            self.status("error", "internal error handling the request; see the daemon log")

    # -- writing ----------------------------------------------------------------------------

    def _wake(self) -> None:
        self._wakeup.set()

    def status(self, level: str, message: str, rid: Id = None) -> None:
        if level_allows(self.level, level):
            self.outbox.reply(status_frame(level, message, rid))

    def reply(self, body: dict[str, Any]) -> None:
        self.outbox.reply(encode(body))

    async def _write_forever(self) -> None:
        try:
            while True:
                if not await self._send_next():
                    self._wakeup.clear()
                    self._writer_idle = True
                    await self._sleep_until_woken(self._next_delay)
                    self._writer_idle = False
        except (ConnectionError, RuntimeError) as exc:
            log.debug("client %s: writer stopped: %s", self.id, exc)

    async def _send_next(self) -> bool:
        """Send one queued reply or message; False when nothing is ready now."""
        text, queue, message, self._next_delay = self.outbox.next_item()
        if text is not None:
            await self.ws.send_str(text)
        elif queue is not None and message is not None:
            await self._send_topic(queue, message)
        else:
            return False
        return True

    async def _send_inline(self) -> None:
        """Answer from the reader while the writer sleeps and the socket takes data at once:
        saves the hop to the writer task on the command -> report path."""
        transport = self.transport
        if transport is None or getattr(transport, "get_write_buffer_size", lambda: 1)():
            return
        try:
            for _ in range(INLINE_SENDS):
                if not await self._send_next():
                    break
        except (ConnectionError, RuntimeError) as exc:
            log.debug("client %s: inline send failed: %s", self.id, exc)

    async def _sleep_until_woken(self, delay: float | None) -> None:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._wakeup.wait(), delay)

    async def _send_topic(self, queue: TopicQueue, message: SharedMessage) -> None:
        text = message.frame(queue.spelling)
        size = queue.options.fragment_size
        if size and len(text) > size:
            for piece in fragments(text, size, f"publish:{queue.spelling}:{id(message)}"):
                await self.ws.send_str(piece)
        else:
            await self.ws.send_str(text)

    # -- advertise / publish ------------------------------------------------------------------

    async def op_advertise(self, frame: dict[str, Any], t_recv: float) -> None:
        name, _ = topic_name(frame)
        type_name = self._message_type(frame, required=True)
        self._check_may_publish(frame, name)
        topic = self.server.graph.topics.get(name)
        if topic is not None and not topic.accepts(type_name):
            raise ProtocolError(f"advertise: type conflict on {name}: it is {topic.type}, "
                                f"not {type_name}", request_id(frame))
        topic = topic or self.server.graph.relay_topic(name, type_name)
        topic.publishers[self] = type_name
        self.advertised.setdefault(name, set()).add(request_id(frame))
        if get_bool(frame, "latch", False) and topic.robot is None:
            self.latching.add(name)

    async def op_unadvertise(self, frame: dict[str, Any], t_recv: float) -> None:
        name, _ = topic_name(frame)
        ids = self.advertised.get(name)
        if ids is None:
            raise ProtocolError(f"unadvertise: {name} is not advertised by this client",
                                request_id(frame))
        rid = request_id(frame)
        if rid is not None and rid in ids:
            ids.discard(rid)
        else:
            ids.clear()
        if not ids:
            await self.withdraw_topic(name)

    async def withdraw_topic(self, name: str) -> None:
        self.advertised.pop(name, None)
        self.latching.discard(name)
        topic = self.server.graph.topics.get(name)
        if topic is not None:
            topic.publishers.pop(self, None)
            self.server.graph.forget_if_unused(topic)
        if name in COMMAND_TOPICS and not any(t in self.advertised for t in COMMAND_TOPICS):
            await self.server.control.drop_source(self.source)

    async def op_publish(self, frame: dict[str, Any], t_recv: float) -> None:
        name, _ = topic_name(frame)
        topic = self.server.graph.topics.get(name)
        if topic is None:
            raise ProtocolError(f"publish: cannot infer topic type for topic {name} as it is "
                                "not yet advertised", request_id(frame))
        self._check_may_publish(frame, name)
        raw = frame.get("msg", {})
        type_name = self._publish_type(frame, topic, raw)
        try:
            msg = check_message(type_name, raw)
        except MessageError as exc:
            raise ProtocolError(f"publish {name}: {exc}", request_id(frame)) from None
        if topic.robot_in:
            await self._command(frame, name, type_name, msg, t_recv)
        shared = SharedMessage(name, msg)
        if name in self.latching:
            topic.latched = shared
        self.server.fan_out(topic, shared)

    def _publish_type(self, frame: dict[str, Any], topic: Topic, raw: Any) -> str:
        declared = topic.publishers.get(self)
        if "type" in frame:
            declared = self._message_type(frame, required=True)
            if not topic.accepts(declared):
                raise ProtocolError(f"publish: type conflict on {topic.name}: it is "
                                    f"{topic.type}, not {declared}", request_id(frame))
        if declared is not None:
            return declared
        if topic.name == "/cmd_vel" and isinstance(raw, dict) and "twist" in raw:
            return TWIST_STAMPED
        return topic.type

    def _check_may_publish(self, frame: dict[str, Any], name: str) -> None:
        topic = self.server.graph.topics.get(name)
        if topic is not None and topic.robot_out:
            raise ProtocolError(f"{frame['op']}: {name} is published by the robot; clients "
                                "cannot publish to it", request_id(frame))
        if name in COMMAND_TOPICS and not self.may_drive:
            raise ProtocolError(f"{frame['op']}: {name} moves the robot and needs a valid "
                                "token (Authorization: Bearer <token> or ?token=<token>)",
                                request_id(frame))

    def _message_type(self, frame: dict[str, Any], *, required: bool) -> str:
        if "type" not in frame and not required:
            return ""
        if "type" not in frame:
            raise ProtocolError(f"{frame['op']}: missing field 'type'", request_id(frame))
        try:
            type_name = normalize_type(frame["type"])
        except MessageError as exc:
            raise ProtocolError(f"{frame['op']}: {exc}", request_id(frame)) from None
        if not has_type(type_name):
            raise ProtocolError(f"{frame['op']}: unknown message type {frame['type']!r}",
                                request_id(frame))
        return type_name

    # -- commands -----------------------------------------------------------------------------

    async def _command(self, frame: dict[str, Any], name: str, type_name: str,
                       msg: dict[str, Any], t_recv: float) -> None:
        rid = request_id(frame)
        try:
            if name == "/estop":
                await self._estop(bool(msg["data"]))
                return
            twist, cmd_id, t_sent = self._parse_command(name, type_name, msg)
        except CommandError as exc:
            raise ProtocolError(f"publish {name}: msg.{exc}; not applied", rid) from None
        applied = await self.server.control.submit(self.source, twist, t_recv=t_recv,
                                                   cmd_id=cmd_id, t_sent_ms=t_sent)
        if not applied.accepted:
            self._refused(name, applied.error or "command not applied", rid)

    def _parse_command(self, name: str, type_name: str,
                       msg: dict[str, Any]) -> tuple[Any, Id, float | None]:
        if name == "/stamped_cmd_vel":
            try:
                body = orjson.loads(msg["data"])  # refuses NaN, Infinity, overflow
            except ValueError as exc:
                raise CommandError(f"data: not a JSON command: {exc}") from None
            if not isinstance(body, dict):
                raise CommandError("data: expected a JSON object")
            return parse_twist(body, extra=STAMP_FIELDS, prefix="data."), *parse_stamp(
                body, "data.")
        if type_name == TWIST_STAMPED:
            return parse_twist(msg["twist"], prefix="twist."), None, None
        assert type_name == TWIST
        return parse_twist(msg), None, None

    async def _estop(self, engage: bool) -> None:
        if engage:
            await self.server.control.engage_estop(f"rosbridge client {self.id} ({self.peer})")
        else:
            self.server.control.release_estop()

    def _refused(self, name: str, reason: str, rid: Id) -> None:
        now = time.monotonic()
        if now - self._refusals.get(reason, -1e9) >= REFUSAL_REPEAT_S:
            self._refusals[reason] = now
            self.status("error", f"publish {name}: command refused: {reason}", rid)

    # -- subscribe ----------------------------------------------------------------------------

    async def op_subscribe(self, frame: dict[str, Any], t_recv: float) -> None:
        name, spelling = topic_name(frame)
        rid = request_id(frame)
        options = self._subscribe_options(frame)
        type_name = self._message_type(frame, required=False)
        topic = self.server.graph.topics.get(name)
        if topic is None and not type_name:
            raise ProtocolError(f"subscribe: unknown topic {name}; give a 'type' to wait for "
                                "a publisher", rid)
        if topic is not None and type_name and not topic.accepts(type_name):
            raise ProtocolError(f"subscribe: type conflict on {name}: it is {topic.type}, "
                                f"not {type_name}", rid)
        topic = topic or self.server.graph.relay_topic(name, type_name)
        queue = self.outbox.topics.get(name)
        if queue is None:
            state = topic.robot.state if topic.robot is not None else False
            queue = self.outbox.topics[name] = TopicQueue(name, spelling, state)
        queue.set_entry(rid, options)
        first = self not in topic.subscribers
        topic.subscribers.add(self)
        if first:
            self.server.send_latest(topic, self)

    def _subscribe_options(self, frame: dict[str, Any]) -> SubscribeOptions:
        throttle_ms = get_number(frame, "throttle_rate", 0)
        queue_length = get_int(frame, "queue_length", 0) or 0
        fragment_size = get_int(frame, "fragment_size", None)
        compression = frame.get("compression", "none")
        if compression not in COMPRESSIONS:
            raise ProtocolError(f"subscribe: field 'compression': expected one of "
                                f"{', '.join(COMPRESSIONS)}", request_id(frame))
        if compression != "none":
            raise ProtocolError(f"subscribe: compression {compression!r} is not supported by "
                                "this server; use 'none'", request_id(frame))
        if fragment_size == 0:
            raise ProtocolError("subscribe: field 'fragment_size': must be positive",
                                request_id(frame))
        return SubscribeOptions(throttle_ms / 1e3, queue_length, fragment_size)

    async def op_unsubscribe(self, frame: dict[str, Any], t_recv: float) -> None:
        name, _ = topic_name(frame)
        queue = self.outbox.topics.get(name)
        if queue is None:
            return
        rid = request_id(frame)
        if rid is not None and rid in queue.entries:
            queue.remove_entry(rid)
        else:
            queue.entries.clear()
        if not queue.entries:
            self.drop_subscription(name)

    def drop_subscription(self, name: str) -> None:
        self.outbox.topics.pop(name, None)
        topic = self.server.graph.topics.get(name)
        if topic is not None:
            topic.subscribers.discard(self)
            self.server.graph.forget_if_unused(topic)

    # -- services -----------------------------------------------------------------------------

    async def op_call_service(self, frame: dict[str, Any], t_recv: float) -> None:
        name, spelling = topic_name(frame, "service")
        rid = request_id(frame)
        if "timeout" in frame:
            get_number(frame, "timeout", 0)
        if name in rosapi.SERVICES:
            try:
                values = rosapi.call(self.server.graph, name, frame.get("args"))
            except rosapi.ServiceError as exc:
                self.service_response(spelling, str(exc), False, rid)
                return
            self.service_response(spelling, values, True, rid, get_int(frame, "fragment_size",
                                                                       None))
            return
        provided = self.server.graph.services.get(name)
        if provided is None:
            self.service_response(spelling, f"Service {name} does not exist", False, rid)
            return
        self._forward_call(frame, provided, spelling, rid)

    def service_response(self, spelling: str, values: Any, result: bool, rid: Id,
                         fragment_size: int | None = None) -> None:
        body: dict[str, Any] = {"op": "service_response", "service": spelling,
                                "values": values, "result": result}
        if rid is not None:
            body["id"] = rid
        text = encode(body)
        if fragment_size and len(text) > fragment_size:
            for piece in fragments(text, fragment_size, rid if rid is not None else spelling):
                self.outbox.reply(piece)
        else:
            self.outbox.reply(text)

    def _forward_call(self, frame: dict[str, Any], provided: ProvidedService, spelling: str,
                      rid: Id) -> None:
        args = frame.get("args", {})
        if not isinstance(args, dict | list):
            raise ProtocolError("call_service: field 'args': expected an object or a list", rid)
        call_id = self.server.graph.next_call_id(provided.name)
        pending = PendingCall(self, rid, spelling, provided)
        self.server.graph.pending[call_id] = pending
        if "timeout" in frame:
            pending.timer = asyncio.get_running_loop().call_later(
                get_number(frame, "timeout", 0), self.server.fail_call, call_id,
                f"Service {provided.name} timed out")
        provided.provider.reply({"op": "call_service", "id": call_id,
                                 "service": provided.name, "args": args})

    async def op_service_response(self, frame: dict[str, Any], t_recv: float) -> None:
        rid = request_id(frame)
        get_str(frame, "service")
        result = get_bool(frame, "result", False) if "result" in frame else None
        if result is None:
            raise ProtocolError("service_response: missing field 'result'", rid)
        pending = self.server.graph.pending.get(str(rid)) if rid is not None else None
        if pending is None or pending.service.provider is not self:
            raise ProtocolError(f"service_response: no call with id {rid!r} is waiting for "
                                "this client", rid)
        values = frame.get("values", {})
        del self.server.graph.pending[str(rid)]
        if pending.timer is not None:
            pending.timer.cancel()
        pending.caller.service_response(pending.spelling, values, result, pending.caller_id)

    async def op_advertise_service(self, frame: dict[str, Any], t_recv: float) -> None:
        name, _ = topic_name(frame, "service")
        rid = request_id(frame)
        try:
            type_name = normalize_type(frame.get("type"), "srv")
        except MessageError as exc:
            raise ProtocolError(f"advertise_service: {exc}", rid) from None
        if name in rosapi.SERVICES:
            raise ProtocolError(f"advertise_service: {name} is provided by the daemon", rid)
        old = self.server.graph.services.get(name)
        if old is not None and old.provider is not self:
            self.server.withdraw_service(old, f"Service {name} was re-advertised")
        self.server.graph.services[name] = ProvidedService(name, type_name, self)

    async def op_unadvertise_service(self, frame: dict[str, Any], t_recv: float) -> None:
        name, _ = topic_name(frame, "service")
        provided = self.server.graph.services.get(name)
        if provided is None or provided.provider is not self:
            raise ProtocolError(f"unadvertise_service: {name} is not advertised by this "
                                "client", request_id(frame))
        self.server.withdraw_service(provided, f"Service {name} was unadvertised")

    # -- misc ---------------------------------------------------------------------------------

    async def op_set_level(self, frame: dict[str, Any], t_recv: float) -> None:
        level = frame.get("level")
        if level not in STATUS_LEVELS:
            raise ProtocolError(f"set_level: field 'level': expected one of "
                                f"{', '.join(STATUS_LEVELS)}", request_id(frame))
        self.level = level

    async def op_fragment(self, frame: dict[str, Any], t_recv: float) -> None:
        joined = self.defrag.add(frame)
        if joined is not None:
            await self.handle_text(joined, t_recv, nested=True)

    async def close(self) -> None:
        """Brake if this client was driving, then forget everything it set up."""
        await self.server.control.drop_source(self.source)
        for name in list(self.outbox.topics):
            self.drop_subscription(name)
        for name in list(self.advertised):
            topic = self.server.graph.topics.get(name)
            if topic is not None:
                topic.publishers.pop(self, None)
                self.server.graph.forget_if_unused(topic)
        self.advertised.clear()
        self.latching.clear()
