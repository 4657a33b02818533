# cbor and cbor-raw subscriptions over a real WebSocket: one binary frame per message, shared
# by subscribers, JSON clients untouched, png refused with a status error.
from __future__ import annotations

import contextlib
import json
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import aiohttp
import cbor2
import numpy as np
from mcap_ros2._dynamic import generate_dynamic

from daemon.messages.definitions import LASER_SCAN, ODOMETRY
from daemon.messages.msgtypes import full_text
from tests.support.in_process_daemon import InProcessDaemon

TIMEOUT = 10.0


def decode(type_name: str, data: bytes) -> Any:
    return generate_dynamic(type_name, full_text(type_name))[type_name](data)


@asynccontextmanager
async def connect(robot: InProcessDaemon) -> AsyncIterator[aiohttp.ClientWebSocketResponse]:
    async with aiohttp.ClientSession() as session, session.ws_connect(robot.ws_url) as ws:
        yield ws


async def next_frame(ws: aiohttp.ClientWebSocketResponse, kind: aiohttp.WSMsgType) -> Any:
    while True:
        message = await ws.receive(timeout=TIMEOUT)
        assert message.type in (aiohttp.WSMsgType.TEXT, aiohttp.WSMsgType.BINARY), message
        if message.type == kind:
            return message.data


async def test_cbor_raw_carries_cdr_with_the_server_clock(robot: InProcessDaemon) -> None:
    async with connect(robot) as ws:
        await ws.send_json({"op": "subscribe", "topic": "/odom", "compression": "cbor-raw"})
        body = cbor2.loads(await next_frame(ws, aiohttp.WSMsgType.BINARY))
        assert body["op"] == "publish" and body["topic"] == "/odom"
        msg = body["msg"]
        assert set(msg) == {"secs", "nsecs", "bytes"} and msg["bytes"][:4] == b"\x00\x01\x00\x00"
        odom = decode(ODOMETRY, msg["bytes"])
        assert odom.header.frame_id == "odom" and odom.child_frame_id == "base_link"
        sent = msg["secs"] + msg["nsecs"] / 1e9
        stamp = odom.header.stamp.sec + odom.header.stamp.nanosec / 1e9
        assert 0 <= sent - stamp < 5.0  # the clock at send, not the message stamp


async def barrier(ws: aiohttp.ClientWebSocketResponse) -> None:
    """A service round trip: every op this client sent before it has been handled."""
    await ws.send_json({"op": "call_service", "service": "/rosapi/get_time", "id": "barrier"})
    while True:
        data = await next_frame(ws, aiohttp.WSMsgType.TEXT)
        if json.loads(data).get("id") == "barrier":
            return


async def relay(robot: InProcessDaemon, type_name: str, msg: dict[str, Any],
                compressions: tuple[str, ...]) -> list[Any]:
    """One client publishes ``msg`` on /relayed; one subscriber per compression receives it."""
    async with connect(robot) as talker, contextlib.AsyncExitStack() as stack:
        listeners = [await stack.enter_async_context(connect(robot)) for _ in compressions]
        for ws, compression in zip(listeners, compressions, strict=True):
            await ws.send_json({"op": "subscribe", "topic": "/relayed", "type": type_name,
                                "compression": compression})
            await barrier(ws)
        await talker.send_json({"op": "advertise", "topic": "/relayed", "type": type_name})
        await talker.send_json({"op": "publish", "topic": "/relayed", "msg": msg})
        return [await next_frame(ws, aiohttp.WSMsgType.TEXT if c == "none"
                                 else aiohttp.WSMsgType.BINARY)
                for ws, c in zip(listeners, compressions, strict=True)]


SCAN = {"header": {"stamp": {"sec": 1700000000, "nanosec": 500000000}, "frame_id": "laser"},
        "angle_min": -1.0, "angle_max": 1.0, "angle_increment": 1.0, "range_max": 12.0,
        "ranges": [1.0, None, 2.5], "intensities": [1, 1, 1]}


async def test_cbor_and_json_clients_get_the_same_scan(robot: InProcessDaemon) -> None:
    raw, values, plain = await relay(robot, LASER_SCAN, SCAN, ("cbor-raw", "cbor", "none"))
    raw_scan = decode(LASER_SCAN, cbor2.loads(raw)["msg"]["bytes"])
    cbor_scan = cbor2.loads(values)["msg"]
    json_scan = json.loads(plain)["msg"]
    ranges = np.asarray(raw_scan.ranges, np.float32)
    assert ranges[0] == 1.0 and np.isnan(ranges[1]) and ranges[2] == 2.5
    assert cbor_scan["ranges"].tag == 85
    assert np.array_equal(np.frombuffer(cbor_scan["ranges"].value, "<f4"), ranges,
                          equal_nan=True)
    assert cbor_scan["header"]["stamp"] == {"sec": 1700000000, "nanosec": 500000000}
    assert json_scan["ranges"] == [1.0, None, 2.5]  # the JSON path is unchanged


async def test_subscribers_share_one_encoded_frame(robot: InProcessDaemon) -> None:
    first, second = await relay(robot, "std_msgs/msg/String", {"data": "hi"},
                                ("cbor-raw", "cbor-raw"))
    assert first == second  # same secs/nsecs too: encoded once, at the first send
    assert cbor2.loads(first)["msg"]["bytes"] == b"\x00\x01\x00\x00\x03\x00\x00\x00hi\x00"


async def test_png_is_refused_with_a_status_error(robot: InProcessDaemon) -> None:
    async with connect(robot) as ws:
        await ws.send_json({"op": "subscribe", "id": "s1", "topic": "/odom",
                            "compression": "png"})
        status = json.loads(await next_frame(ws, aiohttp.WSMsgType.TEXT))
    assert status["op"] == "status" and status["level"] == "error" and status["id"] == "s1"
    assert "png" in status["msg"] and "cbor-raw" in status["msg"]
