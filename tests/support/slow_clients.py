# Slow and hostile WebSocket clients for tests: raw masked frames, and a stream of big scans.
from __future__ import annotations

import asyncio
import base64
import math
import os
import socket
import time
from dataclasses import dataclass, field

import numpy as np

from daemon.telemetry import SCAN
from tests.support.in_process_daemon import InProcessDaemon


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




def stalled_client(port: int, frames: list[str], subprotocol: str = "") -> socket.socket:
    """Handshake (offering ``subprotocol`` if given), send ``frames``, then never read again
    (tiny receive buffer)."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.settimeout(10)
    sock.connect(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    offer = f"Sec-WebSocket-Protocol: {subprotocol}\r\n" if subprotocol else ""
    sock.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                  f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n{offer}"
                  "Sec-WebSocket-Version: 13\r\n\r\n").encode())
    response = b""
    while b"\r\n\r\n" not in response:
        response += sock.recv(1)  # byte by byte: leave every later byte unread
    assert response.startswith(b"HTTP/1.1 101"), response
    for frame in frames:
        sock.sendall(masked_text_frame(frame))
    return sock
