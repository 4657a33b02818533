# The Foxglove WebSocket server under bad input: malformed frames, bad messages, oversized
# frames, floods and a client that never reads — answered, bounded, and the tick runs on.
from __future__ import annotations

import asyncio
import json
import socket
import time
from collections.abc import AsyncIterator
from pathlib import Path

import aiohttp
import pytest

from daemon.bench.rosbridge_flood import LoopProbe, MachineCanary
from daemon.messages import cdr
from tests.support.foxglove import connect, publish_frame
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.net import free_port
from tests.support.rosbridge import OWNER, TWIST, WITH_TOKEN, stall_limit_ms
from tests.support.slow_clients import publish_scans, stalled_client
from tests.support.wait import eventually

STALL_S = 3.0
FLOOD = 5000  # frames: the burst (2000) and three seconds of the rate (1000/s)
ADVERTISE_CMD_VEL = {"op": "advertise", "channels": [
    {"id": 1, "topic": "/cmd_vel", "encoding": "json", "schemaName": "geometry_msgs/msg/Twist"},
    {"id": 2, "topic": "/cmd_vel", "encoding": "cdr", "schemaName": "geometry_msgs/msg/Twist"}]}


@pytest.fixture
async def fox(tmp_path: Path) -> AsyncIterator[InProcessDaemon]:
    port = free_port()
    async with in_process_daemon(tmp_path, f'[foxglove]\nenabled = true\nhost = "127.0.0.1"\n'
                                           f'port = {port}\n' + WITH_TOKEN) as robot:
        robot.fox_port = port  # type: ignore[attr-defined]
        yield robot


def url(robot: InProcessDaemon) -> str:
    return f"ws://127.0.0.1:{robot.fox_port}/"  # type: ignore[attr-defined]


BAD_TEXT = [
    "not json", "[]", '{"op": 5}', '{"op": "nope"}', "[" * 100_000,
    '{"op": "subscribe", "subscriptions": 3}',
    '{"op": "subscribe", "subscriptions": [{"id": true, "channelId": 1}]}',
    '{"op": "subscribe", "subscriptions": [{"id": -1, "channelId": 1}]}',
    '{"op": "subscribe", "subscriptions": [{"id": 1099511627776, "channelId": 1}]}',
    '{"op": "subscribe", "subscriptions": [{"id": 1.5, "channelId": 1}]}',
    '{"op": "subscribe", "subscriptions": [{"id": 1, "channelId": NaN}]}',
    '{"op": "subscribe", "subscriptions": [{"id": 1, "channelId": 1e308}]}',
    '{"op": "subscribe", "subscriptions": [{"id": 1, "channelId": 99999}]}',
    '{"op": "subscribe", "subscriptions": ["x"]}',
    '{"op": "unsubscribe", "subscriptionIds": [12345]}',
    '{"op": "advertise", "channels": [{"id": 5, "topic": "/cmd_vel", "encoding": "json"}]}',
    '{"op": "advertise", "channels": [{"id": 5, "topic": "/cmd_vel", "encoding": "json", '
    '"schemaName": "no/such/Type/at/all"}]}',
    '{"op": "advertise", "channels": [{"id": 5, "topic": "", "encoding": "json", '
    '"schemaName": "std_msgs/msg/String"}]}',
    '{"op": "unadvertise", "channelIds": [77]}',
    '{"op": "getParameters", "parameterNames": [1]}',
    '{"op": "fetchAsset", "uri": "file:///etc/passwd", "requestId": 1}',
]
BAD_BINARY = [b"", b"\x09", b"\x01\x00", b"\x02" + bytes(20), publish_frame(4242, b"{}")]
BAD_MESSAGES = [  # (channel, payload): each refused, naming the problem; nothing moves
    (1, b"not json"), (1, b'{"linear": {"x": NaN}}'), (1, b'{"linear": {"x": Infinity}}'),
    (1, b'{"linear": {"x": "fast"}}'), (1, b'{"warp": 9}'), (1, b"[1, 2]"),
    (2, cdr.encode("geometry_msgs/msg/Twist", TWIST)[:20]), (2, b"\xff\xff\x00\x00"),
    (2, b""),
]


async def test_malformed_frames_are_each_answered_and_the_connection_serves_on(
        fox: InProcessDaemon) -> None:
    async with connect(url(fox), headers=OWNER) as client:
        await client.op("advertise")
        await client.ws.send_str(json.dumps(ADVERTISE_CMD_VEL))
        for text in BAD_TEXT:
            await client.ws.send_str(text)
        for data in BAD_BINARY:
            await client.ws.send_bytes(data)
        for channel, payload in BAD_MESSAGES:
            await client.ws.send_bytes(publish_frame(channel, payload))
        # ("not JSON" twice is said once: a text repeats at most every SAY_AGAIN_S)
        expected = len(BAD_TEXT) + len(BAD_BINARY) + len(BAD_MESSAGES) - 1
        statuses = await client.until(
            lambda: len(found := [o for o in client.ops if o["op"] == "status"]) >= expected
            and found, "a status per bad frame")
        assert all(s["level"] == 2 and s["message"] for s in statuses), statuses
        said = [s["message"] for s in statuses]
        assert "publish /cmd_vel: msg.linear.x: must be finite, got nan; not applied" in said
        assert "subscribe: channelId must be an integer 0..4294967295, not 1e+308" in said
        assert "publish /cmd_vel: msg.linear.z: the sample ends before this field" in said
        # still served: a subscription works after all that
        scan = (await client.channels())["/scan"]
        await client.send(op="subscribe", subscriptions=[{"id": 1, "channelId": scan["id"]}])
        await client.until(lambda: client.messages.get(1), "a scan")
    assert not fox.moving()
    health = fox.component("foxglove").health()
    assert health.status == "ok" and health.values["published"] == 0


async def test_an_oversized_frame_from_a_client_without_the_token_closes_it(
        fox: InProcessDaemon) -> None:
    async with connect(url(fox)) as client:
        await client.op("advertise")
        await client.ws.send_str('{"op": "getParameters", "parameterNames": ["' + "x" * 20_000
                                 + '"]}')
        message = await client.ws.receive(timeout=10)
        while message.type in (aiohttp.WSMsgType.TEXT, aiohttp.WSMsgType.BINARY):
            message = await client.ws.receive(timeout=10)
        assert client.ws.close_code == aiohttp.WSCloseCode.MESSAGE_TOO_BIG


async def test_a_frame_flood_is_throttled_and_the_tick_runs_on(fox: InProcessDaemon) -> None:
    server = fox.component("foxglove")
    async with connect(url(fox)) as client:
        await client.op("advertise")
        ticks_before, t0 = fox.daemon.latency.ticks, time.monotonic()
        async with MachineCanary() as canary, LoopProbe() as probe:
            for _ in range(FLOOD // 2):  # more than the burst: reading pauses
                await client.ws.send_str('{"op": "nope"}')
                await client.ws.send_bytes(publish_frame(1, b"{}"))
            await client.send(op="getParameters", parameterNames=["robot.wheel_radius"],
                              id="after")
            await client.op("parameterValues", "the answer after the flood", within=60)
        elapsed = time.monotonic() - t0
        ticks = fox.daemon.latency.ticks - ticks_before
        assert ticks >= int(elapsed * 50) // 2
        assert probe.longest_stall_s * 1e3 < stall_limit_ms(canary.longest_gap_ms)
        assert server.health().values["throttled_frames"] > 0
        statuses = [o for o in client.ops if o["op"] == "status"]
        assert 0 < len(statuses) <= 10  # each text said once a while, not per frame
    assert not fox.moving()


async def test_a_client_that_never_reads_costs_nobody_anything(fox: InProcessDaemon) -> None:
    server = fox.component("foxglove")
    channel_ids = {c.topic.name: c.id for c in server.channels.values()}
    subscribe = json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i, "channelId": channel_ids[t]} for i, t in enumerate(("/scan", "/odom", "/tf"))]})
    async with connect(url(fox)) as healthy:
        await healthy.op("advertise")
        sock = await asyncio.to_thread(stalled_client, fox.fox_port,  # type: ignore[attr-defined]
                                       [subscribe], "foxglove.websocket.v1")
        try:
            await eventually(lambda: any(len(c.subscriptions) == 3
                                         for c in server.clients.values()),
                             "the stalled client's subscriptions")
            stalled = next(c for c in server.clients.values() if len(c.subscriptions) == 3)
            stalled.ws._req.transport.get_extra_info("socket").setsockopt(
                socket.SOL_SOCKET, socket.SO_SNDBUF, 8192)
            await healthy.send(op="subscribe", subscriptions=[
                {"id": 1, "channelId": channel_ids["/scan"]},
                {"id": 2, "channelId": channel_ids["/odom"]}])
            ticks_before = fox.daemon.latency.ticks
            stop = asyncio.Event()
            scans = asyncio.create_task(publish_scans(fox, stop))
            t_end = time.monotonic() + STALL_S
            async with MachineCanary() as canary, LoopProbe() as probe:
                while time.monotonic() < t_end:
                    await healthy.read(0.05)
            stop.set()
            published = await scans
            await healthy.until(lambda: len(healthy.messages.get(1, [])) >= published // 2,
                                "the healthy client's scans")
            assert len(healthy.messages.get(2, [])) >= int(STALL_S * 20) // 4
            # the stalled client's queues: one message per state topic, bounded for events
            assert all(len(q) <= (1 if stalled.subscriptions[i].topic.state
                                  else stalled.budget.queue_messages)
                       for i, q in stalled._queues.items())
            ticks = fox.daemon.latency.ticks - ticks_before
            assert ticks >= int(STALL_S * 50) // 2
            assert probe.longest_stall_s * 1e3 < stall_limit_ms(canary.longest_gap_ms)
        finally:
            sock.close()
        await eventually(lambda: len(server.clients) == 1, "the stalled client to go")
