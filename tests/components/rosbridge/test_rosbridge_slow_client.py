# A subscriber that stops reading must not delay the control tick or any other client.
from __future__ import annotations

import asyncio
import json
import socket
import time
from pathlib import Path

from daemon.bench.rosbridge_flood import LoopProbe, MachineCanary
from daemon.components.rosbridge.outbox import EVENT_QUEUE
from tests.support.in_process_daemon import in_process_daemon
from tests.support.rosbridge import connect, stall_limit_ms
from tests.support.slow_clients import publish_scans, stalled_client
from tests.support.wait import eventually

STALL_S = 5.0


async def test_stalled_subscriber_costs_nobody_anything(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path) as robot, connect(robot.ws_url) as healthy:
        port = int(robot.ws_url.rsplit(":", 1)[1].strip("/"))
        bridge = robot.component("rosbridge")
        frames = [json.dumps({"op": "subscribe", "topic": t}) for t in ("/scan", "/odom", "/tf")]
        sock = await asyncio.to_thread(stalled_client, port, frames)
        try:
            await eventually(lambda: len(bridge.clients) == 2
                             and any("/tf" in c.outbox.topics
                                     for c in bridge.clients.values()),
                             "the stalled client's subscriptions")
            stalled = next(c for c in bridge.clients.values() if "/tf" in c.outbox.topics)
            # a small send buffer stands in for a congested radio link: without it the
            # kernel would absorb several megabytes before the server's writer felt anything
            assert stalled.transport is not None
            stalled.transport.get_extra_info("socket").setsockopt(
                socket.SOL_SOCKET, socket.SO_SNDBUF, 8192)
            await healthy.send(op="subscribe", topic="/odom")
            await healthy.send(op="subscribe", topic="/scan")
            await healthy.send(op="advertise", topic="/cmd_vel", type="geometry_msgs/Twist")
            ticks_before = robot.daemon.latency.ticks
            stop = asyncio.Event()
            scans = asyncio.create_task(publish_scans(robot, stop))
            t_end = time.monotonic() + STALL_S
            async with MachineCanary() as canary, LoopProbe() as probe:
                while time.monotonic() < t_end:
                    await healthy.send(op="publish", topic="/cmd_vel",
                                       msg={"linear": {"x": 0.1}, "angular": {"z": 0.0}})
                    await asyncio.sleep(0.01)
            stop.set()
            published_scans = await scans
            latest_odom = await healthy.expect(
                lambda m: m.get("topic") == "/odom"
                and m["msg"]["header"]["stamp"]["sec"] + m["msg"]["header"]["stamp"][
                    "nanosec"] * 1e-9 > time.time() - 2.0, what="a fresh /odom")
            assert latest_odom
            # the healthy client got (nearly) every scan and steady odometry while the other
            # client read nothing at all
            assert len(healthy.published("/scan")) >= published_scans // 2
            assert len(healthy.published("/odom")) >= int(STALL_S * 20) // 4
            # the stalled client's writer is blocked; its queues stayed bounded: one message
            # for a state topic (/scan, /odom: old messages replaced, not piled up), at most
            # EVENT_QUEUE for an event topic (/tf carries transforms of several publishers)
            assert all(len(q.queue) <= (1 if q.state else EVENT_QUEUE)
                       for q in stalled.outbox.topics.values())
            assert len(stalled.outbox.topics["/scan"].queue) <= 1
            assert stalled.outbox.topics["/scan"].dropped > 0
            assert stalled.outbox.dropped > 0
            # the tick kept running and the loop never stalled near the deadman (how late
            # each tick was is a figure for `arbiterd bench`, not a test on a shared machine)
            ticks = robot.daemon.latency.ticks - ticks_before
            assert ticks >= int(STALL_S * 50) // 2
            assert probe.longest_stall_s * 1e3 < stall_limit_ms(canary.longest_gap_ms)
        finally:
            sock.close()
        await eventually(lambda: len(bridge.clients) == 1, "the stalled client to go")
