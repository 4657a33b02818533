# The command fast paths equal the general ones: routes, the held answer, the report's text.
from __future__ import annotations

import asyncio
import json
import random
import time
from pathlib import Path
from typing import Any

import aiohttp
import orjson
import pytest
from aiohttp import web
from aiohttp.test_utils import TestServer
from hypothesis import given, settings
from hypothesis import strategies as st

from daemon.commands import (
    STAMP_FIELDS,
    CommandError,
    Twist,
    parse_stamp,
    parse_twist,
    plain_stamped,
)
from daemon.components.rosbridge.access import Authority
from daemon.components.rosbridge.codec import ProtocolError, check_frame, encode
from daemon.components.rosbridge.graph import Topic
from daemon.components.rosbridge.outbox import Outbox, SharedMessage, SubscribeOptions, TopicQueue
from daemon.components.rosbridge.route import Route, fast_frame
from daemon.components.rosbridge.session import ClientSession
from daemon.components.rosbridge.writer import text_frame
from daemon.messages.convert import latency_msg, latency_msg_json
from daemon.messages.definitions import STRING, TWIST
from daemon.messages.msgtypes import MessageError, check_message
from daemon.telemetry import LatencyReport
from daemon.topics import TopicIn
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rosbridge import WITH_TOKEN, bridge

STAMPED = "/stamped_cmd_vel"
JSON = st.recursive(st.none() | st.booleans() | st.integers(-2**63, 2**63 - 1)
                    | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=8),
                    lambda inner: st.lists(inner, max_size=3)
                    | st.dictionaries(st.text(max_size=6), inner, max_size=3), max_leaves=8)


async def _nothing(_: Any) -> None:
    return None


def _route(type_name: str) -> Route:
    robot = TopicIn("/t", type_name, _nothing)
    return Route(Topic("/t", type_name, robot), robot, type_name)


def _general_check(type_name: str, raw: Any) -> dict[str, Any]:
    try:
        return check_message(type_name, raw)
    except MessageError as exc:
        raise ProtocolError(f"publish /t: {exc}") from None


def _outcome(check: Any, type_name: str, raw: Any) -> tuple[str, Any]:
    try:
        return "ok", check(type_name, raw)
    except ProtocolError as exc:
        return "refused", exc.message


@settings(max_examples=300, deadline=None)
@given(raw=JSON | st.fixed_dictionaries({"data": JSON}) | st.fixed_dictionaries(
    {"data": st.text()}, optional={"extra": JSON}))
def test_a_routes_message_check_is_check_message(raw: Any) -> None:
    for type_name in (STRING, TWIST):
        route = _route(type_name)
        fast = _outcome(lambda _, value, route=route: route.check(value), type_name, raw)
        assert fast == _outcome(_general_check, type_name, raw)


@settings(max_examples=300, deadline=None)
@given(frame=st.dictionaries(st.sampled_from(["op", "topic", "id", "type", "msg", "latch"]),
                             JSON | st.just("publish") | st.just(STAMPED), max_size=5))
def test_a_route_takes_only_frames_the_general_path_accepts_unchanged(frame: Any) -> None:
    if fast_frame(frame) is None:
        return
    assert check_frame(frame) is frame
    assert frame["op"] == "publish" and "type" not in frame and isinstance(frame["topic"], str)


@settings(max_examples=200, deadline=None)
@given(cmd_id=st.none() | st.text() | st.integers(-2**63, 2**63 - 1),
       t_sent=st.none() | st.floats(allow_nan=False, allow_infinity=False),
       times=st.tuples(st.floats(0, 2e12), st.floats(0, 2e12), st.floats(0, 1e3)),
       source=st.text())
def test_the_reports_json_text_is_the_general_encoding(cmd_id: Any, t_sent: Any,
                                                       times: Any, source: str) -> None:
    report = LatencyReport(cmd_id, t_sent, times[0], times[1], times[2], source)
    assert latency_msg_json(report) == encode(latency_msg(report))
    shared = SharedMessage("/latency_reports", report, latency_msg)
    assert json.loads(shared.msg_json()) == latency_msg(report)


# -- the held answer -----------------------------------------------------------------------------


def _outbox(options: SubscribeOptions | None = None) -> tuple[Outbox, TopicQueue]:
    options = options or SubscribeOptions()
    outbox = Outbox(lambda: None, clock=lambda: 0.0)
    queue = TopicQueue("/r", "/r", state=False)
    queue.set_entry(None, options)
    outbox.add_queue(queue)
    return outbox, queue


def _drain(outbox: Outbox) -> list[Any]:
    items = []
    while True:
        reply, _, message, _ = outbox.next_item()
        if reply is None and message is None:
            return items
        items.append(reply if reply is not None else message)


def test_a_held_answer_is_the_one_message_the_queue_would_send() -> None:
    outbox, queue = _outbox()
    message = SharedMessage("/r", {"data": "a"})
    outbox.hold()
    outbox.offer("/r", message)
    assert outbox.has_ready() and not queue.queue
    assert outbox.take_held() == (queue, message)
    assert not outbox.has_ready() and not outbox.holding


def test_anything_after_a_held_answer_keeps_the_general_order() -> None:
    outbox, _ = _outbox()
    first, second = SharedMessage("/r", {"data": "1"}), SharedMessage("/r", {"data": "2"})
    outbox.hold()
    outbox.offer("/r", first)
    outbox.reply("status")  # replies go first, as they would have
    outbox.offer("/r", second)
    assert outbox.take_held() is None
    assert _drain(outbox) == ["status", first, second]


def test_a_queue_that_is_not_plain_or_not_empty_is_not_held() -> None:
    for options in (SubscribeOptions(throttle_s=0.1), SubscribeOptions(fragment_size=10),
                    SubscribeOptions(compression="cbor")):
        outbox, queue = _outbox(options)
        outbox.hold()
        outbox.offer("/r", SharedMessage("/r", {"data": "x"}))
        assert outbox.take_held() is None and len(queue.queue) == 1
    outbox, queue = _outbox()
    outbox.offer("/r", SharedMessage("/r", {"data": "before"}))
    outbox.hold()
    outbox.offer("/r", SharedMessage("/r", {"data": "x"}))
    assert outbox.take_held() is None and len(queue.queue) == 2


def test_a_held_answer_of_a_dropped_subscription_goes_nowhere() -> None:
    outbox, _ = _outbox()
    outbox.hold()
    outbox.offer("/r", SharedMessage("/r", {"data": "x"}))
    outbox.drop_queue("/r")
    assert outbox.take_held() is None
    outbox, _ = _outbox()
    outbox.hold()
    outbox.offer("/r", SharedMessage("/r", {"data": "x"}))
    held = outbox.take_held()
    assert held is not None
    outbox.requeue(held)  # not sent at once: into its queue after all
    assert _drain(outbox) == [held[1]]


# -- the session: the route and the general path side by side --------------------------------------


class FakeWS:
    def __init__(self) -> None:
        self.sent: list[str] = []

    async def send_str(self, text: str) -> None:
        self.sent.append(text)


class FakeTransport:
    def get_write_buffer_size(self) -> int:
        return 0


def _session(robot: InProcessDaemon, client_id: int, authority: Authority) -> ClientSession:
    server = bridge(robot)
    session = ClientSession(FakeWS(), client_id, "127.0.0.1", graph=server.graph,  # type: ignore[arg-type]
                            control=server.robot, authority=authority, limits=server.limits)
    session.transport = FakeTransport()
    session.writer._idle = True  # the writer task sleeps (not started here)
    return session


async def _take(session: ClientSession, frame: Any) -> list[dict[str, Any]]:
    """One frame as the reader takes it; what the client got for it."""
    ws: Any = session.ws
    _drain(session.outbox)  # the other client's reports, which this test does not compare
    ws.sent.clear()
    session.writer.begin_inline()
    try:
        await session.handle_text(orjson.dumps(frame), time.monotonic())
    finally:
        await session.writer.send_inline(session.transport)
    return [json.loads(text) for text in ws.sent]


def _comparable(answers: list[dict[str, Any]]) -> list[Any]:
    """The answers without what differs between two clients (times, the source)."""
    out: list[Any] = []
    for answer in answers:
        if answer.get("topic") == "/latency_reports":
            report = json.loads(answer["msg"]["data"])
            out.append(("report", sorted(report), report["id"], report["t_sent"]))
        else:
            out.append(answer)
    return out


def _stamped_body(rng: random.Random, seq: int) -> Any:
    good = {"linear": {"x": rng.choice([0.0, 0.1, -0.2, 5.0])},
            "angular": {"z": rng.choice([0.0, 0.3])}, "id": seq, "t_sent": time.time() * 1e3}
    variants = [good, good, good, {**good, "spin": 1}, {**good, "linear": {"x": "fast"}},
                {**good, "linear": {"y": 0.5}}, {**good, "id": True}, [1], "{",
                {**good, "t_sent": "now"}]
    return rng.choice(variants)


def _stamped_frame(rng: random.Random, seq: int) -> dict[str, Any]:
    body = _stamped_body(rng, seq)
    data: Any = body if isinstance(body, str) else json.dumps(body)
    msg = rng.choice([{"data": data}] * 6 + [{"data": 1}, {"data": data, "x": 1}, [], None])
    frame: dict[str, Any] = {"op": "publish", "topic": STAMPED, "msg": msg}
    extra = rng.choice([{}, {}, {"id": f"r{seq}"}, {"id": seq}, {"id": 1.5}, {"id": True},
                        {"type": STRING}, {"type": "std_msgs/msg/Bool"}])
    return {**frame, **extra}


async def test_the_route_answers_as_the_general_path(robot: InProcessDaemon) -> None:
    """The same frames, one client taking routes and one that never does: the same refusals
    (text and id), the same reports, frame for frame."""
    drive = Authority(True, True)
    fast, general = _session(robot, 901, drive), _session(robot, 902, drive)
    general._route = lambda payload: None  # type: ignore[method-assign]
    for session in (fast, general):
        await _take(session, {"op": "subscribe", "topic": "/latency_reports"})
        await _take(session, {"op": "advertise", "topic": STAMPED, "type": STRING})
    rng = random.Random(23)
    seen: set[str] = set()
    for seq in range(300):
        frame = _stamped_frame(rng, seq)
        got_fast = await _take(fast, frame)
        got_general = await _take(general, frame)
        assert _comparable(got_fast) == _comparable(got_general), frame
        seen.update(answer.get("op", "") for answer in got_fast)
    assert fast._routes and seen == {"publish", "status"}  # reports and refusals both
    assert robot.daemon.latency.commands > 0
    for session in (fast, general):
        await session.close()


async def test_a_route_checks_the_clients_access_every_time(robot: InProcessDaemon) -> None:
    session = _session(robot, 903, Authority(True, True))
    await _take(session, {"op": "advertise", "topic": STAMPED, "type": STRING})
    body = json.dumps({"linear": {"x": 0.1}, "id": 1})
    await _take(session, {"op": "publish", "topic": STAMPED, "msg": {"data": body}})
    assert STAMPED in session._routes
    commands = robot.daemon.latency.commands
    session.authority = Authority(True, False)  # what a client without the token has
    answers = await _take(session, {"op": "publish", "topic": STAMPED, "id": "x",
                                    "msg": {"data": body}})
    assert answers and answers[0]["op"] == "status" and answers[0]["id"] == "x"
    assert "needs a valid token" in answers[0]["msg"]
    assert robot.daemon.latency.commands == commands
    await session.close()


async def test_a_route_follows_the_clients_advertised_type(robot: InProcessDaemon) -> None:
    session = _session(robot, 904, Authority(True, True))
    await _take(session, {"op": "advertise", "topic": STAMPED, "type": STRING, "id": "a"})
    body = json.dumps({"linear": {"x": 0.1}, "id": 1})
    await _take(session, {"op": "publish", "topic": STAMPED, "msg": {"data": body}})
    await _take(session, {"op": "unadvertise", "topic": STAMPED})
    assert session._route({"op": "publish", "topic": STAMPED, "msg": {"data": body}}) is None
    await session.close()


async def test_a_client_without_the_token_never_gets_a_route_nor_moves(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, WITH_TOKEN) as robot:
        session = _session(robot, 905, Authority(True, False))
        body = json.dumps({"linear": {"x": 0.3}, "id": 1})
        for i in range(5):
            answers = await _take(session, {"op": "publish", "topic": STAMPED, "id": i,
                                            "msg": {"data": body}})
            assert answers[0]["op"] == "status" and "needs a valid token" in answers[0]["msg"]
        assert not session._routes and not robot.moving()
        assert robot.daemon.latency.commands == 0
        await session.close()


# -- the stamped command's one-pass check ----------------------------------------------------------

NUMBER = st.floats() | st.integers(-10, 10) | st.booleans() | st.none() | st.text(max_size=2)
AXES = st.dictionaries(st.sampled_from(["x", "y", "z", "w"]), NUMBER | st.just(0.0), max_size=4)
FLOAT_AXES = st.dictionaries(st.sampled_from(["x", "y", "z"]), st.floats() | st.just(0.0),
                             max_size=3)
PLAUSIBLE = st.fixed_dictionaries({}, optional={
    "linear": FLOAT_AXES, "angular": FLOAT_AXES, "id": st.integers(-2**63, 2**63 - 1) | st.text(),
    "t_sent": st.floats()})
BODY = PLAUSIBLE | st.dictionaries(st.sampled_from(["linear", "angular", "id", "t_sent", "spin"]),
                       AXES | NUMBER | st.integers(), max_size=5) | JSON


def _general_stamped(body: Any) -> Any:
    try:
        return "ok", (parse_twist(body, extra=STAMP_FIELDS, prefix="data."),
                      *parse_stamp(body, "data."))
    except (CommandError, AttributeError, TypeError) as exc:
        return "refused", str(exc)


@settings(max_examples=500, deadline=None)
@given(body=BODY)
def test_the_one_pass_stamped_check_is_the_general_one(body: Any) -> None:
    plain = plain_stamped(body)
    if plain is not None:  # else the general parse decides, as before
        assert ("ok", plain) == _general_stamped(body)


def test_the_one_pass_stamped_check_takes_the_common_command() -> None:
    body = {"linear": {"x": 0.1}, "angular": {"z": -0.2}, "id": 7, "t_sent": 1.5e12}
    assert plain_stamped(body) == (Twist(0.1, -0.2), 7, 1.5e12)
    assert plain_stamped({**body, "linear": {"x": 0.1, "y": 0.5}}) is None
    assert plain_stamped({**body, "id": True}) is None


# -- the answer written from inside its publisher ------------------------------------------------


@pytest.mark.parametrize("length", [0, 1, 125, 126, 245, 65535, 65536, 70000])
async def test_a_frame_written_to_the_socket_is_the_text_a_client_reads(length: int) -> None:
    """:func:`text_frame` on a real socket: an aiohttp client reads the payload as aiohttp's
    own writer would have sent it, on each side of the 7-, 16- and 64-bit length boundaries."""
    text = ("é" * length)[:length] if length % 2 else "x" * length
    payload = text.encode()

    async def handler(request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse()
        await ws.prepare(request)
        assert isinstance(request.transport, asyncio.WriteTransport) and not ws.compress
        request.transport.write(text_frame(payload))
        await ws.send_str("after")  # aiohttp's writer goes on from where the frame ended
        await ws.receive()
        return ws

    app = web.Application()
    app.router.add_get("/", handler)
    async with TestServer(app) as server, aiohttp.ClientSession() as session, \
            session.ws_connect(server.make_url("/")) as ws:
        assert (await ws.receive_str(timeout=5)) == text
        assert (await ws.receive_str(timeout=5)) == "after"


async def test_a_commands_answer_leaves_from_the_control_loop_in_order(
        robot: InProcessDaemon) -> None:
    """The latency report is written to the socket while the command is applied (the
    statistics are counted after); the client reads each answer whole and in order, with a
    refusal between them answered in its place."""
    async with aiohttp.ClientSession() as session, session.ws_connect(robot.ws_url) as ws:
        await ws.send_json({"op": "subscribe", "topic": "/latency_reports"})
        await ws.send_json({"op": "advertise", "topic": STAMPED, "type": STRING})
        before = robot.daemon.latency.commands
        for seq in range(40):
            data = "{" if seq == 20 else json.dumps({"linear": {"x": 0.05}, "id": seq})
            await ws.send_json({"op": "publish", "topic": STAMPED, "id": f"p{seq}",
                                "msg": {"data": data}})
            answer = await ws.receive_json(timeout=5)
            if seq == 20:
                assert answer["op"] == "status" and answer["id"] == "p20"
                continue
            assert answer["topic"] == "/latency_reports"
            assert json.loads(answer["msg"]["data"])["id"] == seq
        assert robot.daemon.latency.commands == before + 39
