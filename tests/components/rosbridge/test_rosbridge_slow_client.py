# A subscriber that stops reading must not delay the control tick or any other client.
from __future__ import annotations

import asyncio
import base64
import json
import math
import os
import socket
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from daemon.bench.rosbridge_flood import LoopProbe, MachineCanary
from daemon.components.rosbridge.outbox import EVENT_QUEUE
from daemon.telemetry import SCAN
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rosbridge import connect, stall_limit_ms
from tests.support.wait import eventually

STALL_S = 5.0


def masked_text_frame(text: str) -> bytes:
    """One client-to-server WebSocket text frame (clients must mask)."""
    payload = text.encode()
    mask = os.urandom(4)
    size = len(payload)
    if size < 126:
        header = bytes([0x81, 0x80 | size])
    elif size < 65536:
        header = bytes([0x81, 0x80 | 126]) + size.to_bytes(2, "big")
    else:
        header = bytes([0x81, 0x80 | 127]) + size.to_bytes(8, "big")
    return header + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


def stalled_client(port: int, frames: list[str]) -> socket.socket:
    """Handshake, send ``frames``, then never read again (tiny receive buffer)."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.settimeout(10)
    sock.connect(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                  f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                  "Sec-WebSocket-Version: 13\r\n\r\n").encode())
    response = b""
    while b"\r\n\r\n" not in response:
        response += sock.recv(1)  # byte by byte: leave every later byte unread
    assert response.startswith(b"HTTP/1.1 101"), response
    for frame in frames:
        sock.sendall(masked_text_frame(frame))
    return sock


@dataclass
class BigScan:
    """A 2000-ray revolution (about 40 kB of JSON) with some missing returns."""

    stamp: float
    frame_id: str = "laser"
    angle_min: float = -math.pi
    angle_max: float = math.pi
    angle_increment: float = 2 * math.pi / 2000
    time_increment: float = 0.0
    scan_time: float = 0.1
    range_min: float = 0.1
    range_max: float = 12.0
    ranges: np.ndarray = field(default_factory=lambda: np.where(
        np.arange(2000) % 50 == 0, np.inf, np.random.default_rng(1).uniform(0.2, 11.0, 2000)))
    intensities: np.ndarray = field(default_factory=lambda: np.zeros(0))


async def publish_scans(robot: InProcessDaemon, stop: asyncio.Event) -> int:
    count = 0
    while not stop.is_set():
        robot.ctx.bus.publish(SCAN, BigScan(time.time()))  # type: ignore[arg-type]
        count += 1
        await asyncio.sleep(0.1)
    return count


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
