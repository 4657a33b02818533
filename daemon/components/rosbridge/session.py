# One WebSocket client: reads ops, drives the robot, and writes its queued replies and topics.
from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from aiohttp import WSCloseCode, WSMsgType, web

from daemon.components.rosbridge import access, rosapi, route
from daemon.components.rosbridge.access import Authority
from daemon.components.rosbridge.codec import (
    STATUS_LEVELS,
    Defragmenter,
    Id,
    ProtocolError,
    check_frame,
    encode,
    fragment_count,
    get_bool,
    get_int,
    get_number,
    level_allows,
    over_limit,
    parse_json,
    request_id,
    shown,
    status_frame,
    topic_name,
)
from daemon.components.rosbridge.graph import BridgeGraph, Topic
from daemon.components.rosbridge.limits import Limits, Pacer, RateLimitedLog, TokenBucket
from daemon.components.rosbridge.outbox import (
    FragmentedReply,
    Outbox,
    SharedMessage,
    SubscribeOptions,
    TopicQueue,
)
from daemon.components.rosbridge.route import Route
from daemon.components.rosbridge.writer import Writer
from daemon.coords import missing_required
from daemon.messages.msgtypes import MessageError, check_message, get_type, has_type, normalize_type
from daemon.topics import Inbound, Refusal, TopicIn, TopicOut

if TYPE_CHECKING:
    from daemon.robot import RobotBase

log = logging.getLogger("arbiterd.rosbridge")

COMPRESSIONS = ("none", "png", "cbor", "cbor-raw")
REFUSAL_REPEAT_S = 0.5  # the same refused-command status at most this often per client
THROTTLE_CLOSE_S = 10.0  # a client held to its request rate this long without a break goes

Clock = Callable[[], float]


@dataclass(slots=True)
class Request:
    """One incoming op being handled: its op, frame, receipt time, ``id``, the canonical
    topic or service it names (``""`` for ops that name none) and, for ``advertise`` and
    ``publish``, that topic as the graph had it when the request was checked."""

    op: str
    frame: dict[str, Any]
    t_recv: float
    id: Id
    target: str = ""
    spelling: str = ""
    topic: Topic | None = None


OpHandler = Callable[[Request], Awaitable[None]]

# the ops this server handles, each by its method ``op_<name>``
OPS = ("advertise", "unadvertise", "publish", "subscribe", "unsubscribe", "call_service",
       "service_response", "advertise_service", "unadvertise_service", "set_level",
       "fragment")

# op -> the field naming its topic or service (parsed once, before the access check)
TARGET_FIELDS = {"advertise": "topic", "unadvertise": "topic", "publish": "topic",
                 "subscribe": "topic", "unsubscribe": "topic", "call_service": "service",
                 "service_response": "service", "advertise_service": "service",
                 "unadvertise_service": "service"}


class ClientSession:
    """State and op handlers of one connected client (command source ``ws:<id>``). It is
    handed what it works with: the graph, the control loop, a clock and its authority."""

    def __init__(self, ws: web.WebSocketResponse, client_id: int, peer: str, *,
                 graph: BridgeGraph, control: RobotBase, authority: Authority,
                 limits: Limits, clock: Clock = time.monotonic,
                 bad_input: RateLimitedLog | None = None, pacer: Pacer | None = None) -> None:
        self.ws = ws
        self.id = client_id
        self.peer = peer
        self.graph = graph
        self.robot = control
        self.authority = authority
        self.limits = limits
        self.clock = clock
        self.bad_input = bad_input or RateLimitedLog(log, clock=clock)
        self.source = f"ws:{client_id}"
        #: who sends its messages, for logs
        self.sender = f"rosbridge client {client_id} ({peer})"
        self.transport: asyncio.BaseTransport | None = None
        self.level = "error"
        self.advertised: dict[str, set[Id]] = {}
        self.latching: set[str] = set()
        self.subscriptions = 0  # subscribe ids held, over all topics
        self.outbox = Outbox(lambda: self.writer.wake(), clock)
        self.writer = Writer(ws, self.outbox, limits, pacer or Pacer(limits.fragments_per_second,
                                                                     clock), self._say_once)
        self.defrag = Defragmenter(limits.fragments(authority.may_drive))
        self.frames_in = 0
        self.errors = 0
        self.last_received = clock()
        self._bucket = TokenBucket(limits.ops_per_second, limits.ops_burst, clock)
        self.over_rate = 0  # frames held back for the request rate
        self._throttled_since: float | None = None
        self._refusals: dict[str, float] = {}
        self._ops: dict[str, OpHandler] = {op: getattr(self, f"op_{op}") for op in OPS}
        #: topic spelling -> the publish path the general one let through (see op_publish)
        self._routes: dict[str, Route] = {}

    def __repr__(self) -> str:
        return f"<client {self.id} {self.peer}>"

    @property
    def may_drive(self) -> bool:
        return self.authority.may_drive

    def idle_since(self) -> float | None:
        """When it last sent anything, if it holds nothing (no subscription, topic, service or
        call): an idle connection only takes a slot. None when it holds something."""
        if self.outbox.topics or self.advertised or self.graph.services_of(self) \
                or self.graph.calls_of(self) or self.defrag.pending:
            return None
        return self.last_received

    # -- reading ----------------------------------------------------------------------------

    async def serve(self) -> None:
        """Read frames until the socket closes; the writer runs beside it."""
        writer = asyncio.create_task(self.writer.run(), name=f"rosbridge-writer-{self.id}")
        try:
            async for message in self.ws:
                t_recv = self.last_received = self.clock()
                if message.type in (WSMsgType.TEXT, WSMsgType.BINARY):
                    if not await self._take(message.data, t_recv):
                        break
                elif message.type == WSMsgType.ERROR:
                    self.bad_input(logging.INFO, f"rosbridge client {self.id} ({self.peer}): "
                                   f"refused frame: {self.ws.exception()}; closed")
                    break
        finally:
            writer.cancel()

    async def _take(self, data: str | bytes, t_recv: float) -> bool:
        """Handle one frame from the socket at no more than the client's request rate: over
        it, reading pauses (TCP pushes back on the client), the client is told once a while,
        and a client kept over it for THROTTLE_CLOSE_S is closed. The loop gets a turn after
        every frame (frames already buffered are otherwise read without suspending). False
        when the client is closed."""
        wait = self._bucket.reserve(1.0)
        if wait > 0:
            if not await self._throttle(wait, t_recv):
                return False
        elif self._bucket.left >= self._bucket.burst / 2:
            # a break: the client sent less than its rate for a while (one frame let through
            # because a sleep overran is none, or a steady flood would never be closed)
            self._throttled_since = None
        self.writer.begin_inline(self.transport)  # what the request queues is sent from here
        try:
            await self.handle_text(data, t_recv)
        finally:
            await self.writer.send_inline(self.transport)
        await asyncio.sleep(0)
        return True

    async def _throttle(self, wait: float, now: float) -> bool:
        self.over_rate += 1
        if self._throttled_since is None:
            self._throttled_since = now
        if now - self._throttled_since > THROTTLE_CLOSE_S:
            await self.ws.close(code=WSCloseCode.POLICY_VIOLATION,
                                message=b"too many requests ([rosbridge] ops_per_second)")
            return False
        self._say_once("ops_per_second", over_limit(
            f"too many requests: reading paused ({self.over_rate} requests held back so far)",
            self.limits.ops_per_second, "ops_per_second").message, None)
        await asyncio.sleep(wait)
        return True

    async def handle_text(self, text: str | bytes, t_recv: float, nested: bool = False) -> None:
        """Handle one frame; every refusal is answered here, with the request's ``id``."""
        self.frames_in += 1
        payload: Any = None
        try:
            payload = parse_json(text)
            to = self._route(payload)
            if to is not None:
                await self._publish_to(to, payload, t_recv)
            else:
                request = self._request(check_frame(payload), t_recv, nested)
                await self._ops[request.op](request)
        except ProtocolError as exc:
            self._refuse(exc.message, request_id(payload))
        except Exception as exc:  # a bug: one line in the log, the details at debug level
            self.errors += 1
            self.bad_input(logging.WARNING, f"rosbridge client {self.id} ({self.peer}): request "
                           f"failed: {type(exc).__name__}: {exc}"[:300])
            log.debug("client %s: request failed", self.id, exc_info=True)
            self.status("error", "internal error handling the request; see the daemon log",
                        request_id(payload))

    def _refuse(self, message: str, rid: Id) -> None:
        self.errors += 1
        self.status("error", message, rid)
        self.bad_input(logging.INFO, f"rosbridge client {self.id} ({self.peer}): refused "
                       f"request: {message[:200]}")

    def _request(self, frame: dict[str, Any], t_recv: float, nested: bool) -> Request:
        """The request context: a known op, its target parsed, its access checked."""
        op = frame["op"]
        if op not in self._ops or (nested and op == "fragment"):
            raise ProtocolError(f"unknown operation {shown(op)}; allowed operations: "
                                f"{', '.join(self._ops)}")
        request = Request(op, frame, t_recv, request_id(frame))
        key = TARGET_FIELDS.get(op)
        if key is not None:
            request.target, request.spelling = topic_name(frame, key)
        access.check(op, request.target, self.authority, self._declared_access(request))
        return request

    def _declared_access(self, request: Request) -> access.Access | None:
        """What the robot's incoming topic declares for publishing to it (None otherwise);
        the topic is kept on the request for its handler."""
        if request.op not in ("advertise", "publish"):
            return None
        topic = request.topic = self.graph.topic(request.target)
        robot = topic.robot if topic is not None else None
        return robot.access if isinstance(robot, TopicIn) else None

    # -- replies ----------------------------------------------------------------------------

    def status(self, level: str, message: str, rid: Id = None) -> None:
        if level_allows(self.level, level):
            self.outbox.reply(status_frame(level, message, rid))

    def reply(self, body: dict[str, Any]) -> None:
        self.outbox.reply(encode(body))

    def deliver(self, topic: str, message: SharedMessage) -> None:
        self.outbox.offer(topic, message)

    # -- advertise / publish ------------------------------------------------------------------

    async def op_advertise(self, req: Request) -> None:
        name = req.target
        type_name = self._message_type(req, required=True)
        topic = self.graph.topic(name)
        self._check_not_robot_out(req, topic)
        if topic is not None and not topic.accepts(type_name):
            raise ProtocolError(f"advertise: type conflict on {name}: it is {topic.type}, "
                                f"not {type_name}")
        if name not in self.advertised and len(self.advertised) >= \
                self.limits.max_topics_per_client:
            raise over_limit(f"advertise {name}: this client advertises too many topics",
                             self.limits.max_topics_per_client, "max_topics_per_client")
        topic = self.graph.add_publisher(self, name, type_name)
        self.advertised.setdefault(name, set()).add(req.id)
        if get_bool(req.frame, "latch", False) and topic.robot is None:
            self.latching.add(name)

    async def op_unadvertise(self, req: Request) -> None:
        ids = self.advertised.get(req.target)
        if ids is None:
            raise ProtocolError(f"unadvertise: {req.target} is not advertised by this client")
        if req.id is not None and req.id in ids:
            ids.discard(req.id)
        else:
            ids.clear()
        if not ids:
            await self.withdraw_topic(req.target)

    async def withdraw_topic(self, name: str) -> None:
        self.advertised.pop(name, None)
        self.latching.discard(name)
        self.graph.remove_publisher(self, name)
        if self._moves(name) and not any(self._moves(t) for t in self.advertised):
            await self.robot.drop_source(self.source)

    def _moves(self, name: str) -> bool:
        topic = self.graph.topic(name)
        return topic is not None and isinstance(topic.robot, TopicIn) and topic.robot.moves

    async def op_publish(self, req: Request) -> None:
        name, topic = req.target, req.topic  # the topic the access check saw
        if topic is None:
            raise ProtocolError(f"publish: cannot infer topic type for topic {name} as it is "
                                "not yet advertised")
        self._check_not_robot_out(req, topic)
        raw = req.frame.get("msg", {})
        type_name = self._publish_type(req, topic, raw)
        try:
            msg = check_message(type_name, raw)
        except MessageError as exc:
            raise ProtocolError(f"publish {name}: {exc}") from None
        robot = topic.robot
        if isinstance(robot, TopicIn):
            missing = missing_required(raw, robot.required)
            if missing is not None:
                raise ProtocolError(f"publish {name}: msg.{missing}")
            if robot.access_for is not None:  # this message may need more (a release)
                access.check(req.op, name, self.authority, robot.access_for(msg))
            self._keep_route(req, topic, robot, type_name)
            refusal = await robot.handler(Inbound(name, type_name, msg, self.source,
                                                  self.sender, req.t_recv, self.peer))
            if refusal is not None:
                self._refused_inbound(name, req.id, refusal)
        latch = name in self.latching
        if latch or topic.subscribers:  # nobody to hand it to: nothing to share
            self.graph.publish(topic, SharedMessage(name, msg), latch=latch)

    def _keep_route(self, req: Request, topic: Topic, robot: TopicIn, type_name: str) -> None:
        """After the general path let a publish through: the next ones of the same shape to
        this topic, spelled the same, may take :meth:`_publish_to` (a type the client
        advertised, none in the frame, an access that does not depend on the message)."""
        if "type" in req.frame or topic.publishers.get(self) != type_name \
                or not route.usable(robot) or req.spelling in self._routes:
            return
        if len(self._routes) >= route.MAX_ROUTES:
            self._routes.clear()
        self._routes[req.spelling] = Route(topic, robot, type_name)

    def _route(self, payload: Any) -> Route | None:
        """The route a frame may take: a publish the general path would check exactly as
        it checked the one that made the route. The access is checked again every time."""
        spelling = route.fast_frame(payload)
        if spelling is None:
            return None
        to = self._routes.get(spelling)
        if to is None or not self.authority.allows(to.access) \
                or to.topic.publishers.get(self) != to.type_name:
            return None  # the general path answers (an unadvertise since, another type)
        return to

    async def _publish_to(self, to: Route, frame: dict[str, Any], t_recv: float) -> None:
        """``op_publish`` for a frame :meth:`_route` let through: the same checks, the same
        handler, the same refusals, without the request's layers."""
        name, topic = to.name, to.topic
        msg = to.check(frame.get("msg", {}))
        refusal = await to.handler(Inbound(name, to.type_name, msg, self.source, self.sender,
                                           t_recv, self.peer))
        if refusal is not None:
            self._refused_inbound(name, frame.get("id"), refusal)
        latch = name in self.latching
        if latch or topic.subscribers:
            self.graph.publish(topic, SharedMessage(name, msg), latch=latch)

    def _publish_type(self, req: Request, topic: Topic, raw: Any) -> str:
        declared = topic.publishers.get(self)
        if "type" in req.frame:
            declared = self._message_type(req, required=True)
            if not topic.accepts(declared):
                raise ProtocolError(f"publish: type conflict on {topic.name}: it is "
                                    f"{topic.type}, not {declared}")
        if declared is not None:
            return declared
        if isinstance(topic.robot, TopicIn) and isinstance(raw, dict):
            return _type_of(raw, topic.robot)
        return topic.type

    def _check_not_robot_out(self, req: Request, topic: Topic | None) -> None:
        if topic is not None and topic.robot_out:
            raise ProtocolError(f"{req.op}: {req.target} is published by the robot; clients "
                                "cannot publish to it")

    def _message_type(self, req: Request, *, required: bool) -> str:
        frame = req.frame
        if "type" not in frame and not required:
            return ""
        if "type" not in frame:
            raise ProtocolError(f"{req.op}: missing field 'type'")
        try:
            type_name = normalize_type(frame["type"])
        except MessageError as exc:
            raise ProtocolError(f"{req.op}: {exc}") from None
        if not has_type(type_name):
            raise ProtocolError(f"{req.op}: unknown message type {frame['type']!r}")
        return type_name

    # -- commands -----------------------------------------------------------------------------

    def _refused_inbound(self, name: str, rid: Id, refusal: Refusal) -> None:
        """A message for the robot its owner refused: a status error (one that repeats at
        command rate is said once a while)."""
        message = f"publish {name}: {refusal.reason}"
        if not refusal.repeats:
            raise ProtocolError(message)
        self._say_once(refusal.reason, message, rid)

    def _say_once(self, key: str, message: str, rid: Id) -> None:
        """A status error repeated at most every REFUSAL_REPEAT_S per ``key``."""
        now = self.clock()
        if now - self._refusals.get(key, -1e9) >= REFUSAL_REPEAT_S:
            if len(self._refusals) > 64:
                self._refusals.clear()
            self._refusals[key] = now
            self.status("error", message, rid)

    # -- subscribe ----------------------------------------------------------------------------

    async def op_subscribe(self, req: Request) -> None:
        name = req.target
        options = self._subscribe_options(req.frame)
        type_name = self._message_type(req, required=False)
        topic = self.graph.topic(name)
        if topic is None and not type_name:
            raise ProtocolError(f"subscribe: unknown topic {name}; give a 'type' to wait for "
                                "a publisher")
        if topic is not None and type_name and not topic.accepts(type_name):
            raise ProtocolError(f"subscribe: type conflict on {name}: it is {topic.type}, "
                                f"not {type_name}")
        queue = self.outbox.topics.get(name)
        if (queue is None or req.id not in queue.entries) and \
                self.subscriptions >= self.limits.max_subscriptions_per_client:
            raise over_limit(f"subscribe {name}: this client holds too many subscriptions",
                             self.limits.max_subscriptions_per_client,
                             "max_subscriptions_per_client")
        if queue is None:
            robot = topic.robot if topic is not None else None
            state = robot.state if isinstance(robot, TopicOut) else robot is not None
            queue = TopicQueue(name, req.spelling, state,
                               topic.type if topic is not None else type_name)
            self.outbox.add_queue(queue)
        self.subscriptions += req.id not in queue.entries
        queue.set_entry(req.id, options)
        self.graph.add_subscriber(self, name, type_name)

    def _subscribe_options(self, frame: dict[str, Any]) -> SubscribeOptions:
        throttle_ms = get_number(frame, "throttle_rate", 0)
        queue_length = get_int(frame, "queue_length", 0) or 0
        fragment_size = get_int(frame, "fragment_size", None)
        compression = frame.get("compression", "none")
        if compression not in COMPRESSIONS:
            raise ProtocolError(f"subscribe: field 'compression': expected one of "
                                f"{', '.join(COMPRESSIONS)}")
        if compression == "png":
            raise ProtocolError("subscribe: compression 'png' is not supported by arbiterd; "
                                "use 'cbor-raw' (ROS 2 CDR), 'cbor' or 'none' (JSON)")
        if fragment_size == 0:
            raise ProtocolError("subscribe: field 'fragment_size': must be positive")
        if queue_length > self.limits.max_queue_length:
            raise over_limit(f"subscribe: field 'queue_length': {queue_length} is too large",
                             self.limits.max_queue_length, "max_queue_length")
        return SubscribeOptions(throttle_ms / 1e3, queue_length, fragment_size, compression)

    async def op_unsubscribe(self, req: Request) -> None:
        queue = self.outbox.topics.get(req.target)
        if queue is None:
            return
        if req.id is not None and req.id in queue.entries:
            queue.remove_entry(req.id)
            self.subscriptions -= 1
            if queue.entries:
                return
        self.drop_subscription(req.target)  # its last subscription, or all of them

    def drop_subscription(self, name: str) -> None:
        queue = self.outbox.topics.get(name)
        if queue is not None:
            self.subscriptions -= len(queue.entries)
            self.outbox.drop_queue(name)
        self.graph.remove_subscriber(self, name)

    # -- services -----------------------------------------------------------------------------

    async def op_call_service(self, req: Request) -> None:
        name, spelling, frame = req.target, req.spelling, req.frame
        timeout = get_number(frame, "timeout", 0) if "timeout" in frame else None
        if name in rosapi.SERVICES:
            try:
                values = rosapi.call(self.graph, name, frame.get("args"))
            except rosapi.ServiceError as exc:
                self.service_response(spelling, str(exc), False, req.id)
                return
            self.service_response(spelling, values, True, req.id,
                                  get_int(frame, "fragment_size", None))
            return
        provided = self.graph.service(name)
        if provided is None:
            self.service_response(spelling, f"Service {name} does not exist", False, req.id)
            return
        args = frame.get("args", {})
        if not isinstance(args, dict | list):
            raise ProtocolError("call_service: field 'args': expected an object or a list")
        if self.graph.calls_of(self) >= self.limits.max_pending_calls_per_client:
            raise over_limit(f"call_service {name}: too many of this client's calls are "
                             "waiting for an answer", self.limits.max_pending_calls_per_client,
                             "max_pending_calls_per_client")
        limit = self.limits.call_timeout
        if timeout and timeout < limit:
            seconds, why = timeout, "the call's timeout"
        else:
            seconds, why = limit, "[rosbridge] call_timeout"
        self.graph.forward_call(self, req.id, spelling, provided, args, seconds,
                                f"Service {name} timed out after {seconds:g} s ({why})")

    def service_response(self, spelling: str, values: Any, result: bool, rid: Id,
                         fragment_size: int | None = None) -> None:
        body: dict[str, Any] = {"op": "service_response", "service": spelling,
                                "values": values, "result": result}
        if rid is not None:
            body["id"] = rid
        text = encode(body)
        if not fragment_size or len(text) <= fragment_size:
            self.outbox.reply(text)
        elif fragment_count(text, fragment_size) > self.limits.max_fragments_per_message:
            refusal = over_limit(f"the answer would need {fragment_count(text, fragment_size)} "
                                 f"fragments of {fragment_size}; ask with a larger "
                                 "fragment_size", self.limits.max_fragments_per_message,
                                 "max_fragments_per_message")
            self.service_response(spelling, refusal.message, False, rid)
        else:
            self.outbox.reply(FragmentedReply(text, fragment_size,
                                              rid if rid is not None else spelling))

    async def op_service_response(self, req: Request) -> None:
        result = get_bool(req.frame, "result", False) if "result" in req.frame else None
        if result is None:
            raise ProtocolError("service_response: missing field 'result'")
        values = req.frame.get("values", {})
        if req.id is None or not self.graph.answer_call(self, str(req.id), values, result):
            raise ProtocolError(f"service_response: no call with id {shown(req.id)} is waiting for "
                                "this client")

    async def op_advertise_service(self, req: Request) -> None:
        try:
            type_name = normalize_type(req.frame.get("type"), "srv")
        except MessageError as exc:
            raise ProtocolError(f"advertise_service: {exc}") from None
        if req.target in rosapi.SERVICES:
            raise ProtocolError(f"advertise_service: {req.target} is provided by the daemon")
        current = self.graph.service(req.target)
        if (current is None or current.provider is not self) and \
                self.graph.services_of(self) >= self.limits.max_services_per_client:
            raise over_limit(f"advertise_service {req.target}: this client provides too many "
                             "services", self.limits.max_services_per_client,
                             "max_services_per_client")
        self.graph.advertise_service(self, req.target, type_name)

    async def op_unadvertise_service(self, req: Request) -> None:
        provided = self.graph.service(req.target)
        if provided is None or provided.provider is not self:
            raise ProtocolError(f"unadvertise_service: {req.target} is not advertised by this "
                                "client")
        self.graph.withdraw_service(provided, f"Service {req.target} was unadvertised")

    # -- misc ---------------------------------------------------------------------------------

    async def op_set_level(self, req: Request) -> None:
        level = req.frame.get("level")
        if level not in STATUS_LEVELS:
            raise ProtocolError(f"set_level: field 'level': expected one of "
                                f"{', '.join(STATUS_LEVELS)}")
        self.level = level

    async def op_fragment(self, req: Request) -> None:
        joined = self.defrag.add(req.frame, self.clock())
        if joined is not None:
            await self.handle_text(joined, req.t_recv, nested=True)

    async def close(self) -> None:
        """Brake if this client was driving, then forget everything it set up."""
        await self.robot.drop_source(self.source)
        self.outbox.clear()
        self.subscriptions = 0
        self.advertised.clear()
        self.latching.clear()
        self.graph.forget(self)


def _type_of(raw: dict[str, Any], topic: TopicIn) -> str:
    """The first type the topic accepts whose fields cover the message's (a TwistStamped on
    /cmd_vel without a declared type); its own type when none does."""
    for type_name in topic.accepted_types():
        if set(raw) <= {f.name for f in get_type(type_name).fields}:
            return type_name
    return topic.type
