# rosbridge in tests: a WebSocket client that remembers what it received, and shared settings.
from __future__ import annotations

import json
import math
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

import aiohttp
import numpy as np

from tests.support.in_process_daemon import InProcessDaemon
from tests.support.wait import Deadline

TIMEOUT = 10.0  # for an expected message
#: A drive command.
TWIST = {"linear": {"x": 0.3, "y": 0, "z": 0}, "angular": {"x": 0, "y": 0, "z": 0.2}}
#: A daemon config with a token, and the header of the client that has it.
TOKEN = "s3cret-t0ken"
WITH_TOKEN = f'[security]\ntoken = "{TOKEN}"\n'
OWNER = {"Authorization": f"Bearer {TOKEN}"}
# the deadman (cmd_vel_timeout, 0.5 s) must be able to fire; on a shared 2-core box garbage
# collection and scheduling alone stall a loop for up to ~150 ms, the bugs did for seconds
STALL_LIMIT_MS = 400.0


def stall_limit_ms(machine_stall_ms: float) -> float:
    """STALL_LIMIT_MS on top of what the machine's load did to an idle process meanwhile (the
    in-run baseline of bench.rosbridge_flood.MachineCanary): a busy CI box is no finding."""
    return STALL_LIMIT_MS + machine_stall_ms


class Client:
    """A rosbridge client on an aiohttp WebSocket that remembers everything it received."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.received: list[dict[str, Any]] = []
        self.raw: list[str] = []
        self.calls = 0

    async def send(self, **frame: Any) -> None:
        await self.ws.send_str(json.dumps(frame))

    async def expect(self, predicate: Callable[[dict[str, Any]], bool],
                     within: float = TIMEOUT, what: str = "a message") -> dict[str, Any]:
        """The first message matching ``predicate`` (waits for it)."""
        deadline = Deadline(
            lambda: f"{what}; got {[m.get('op') for m in self.received[-10:]]}", within)
        while (found := next((m for m in self.received if predicate(m)), None)) is None:
            deadline.check()
            await self._read(deadline.remaining())  # one read: a timed-out one ends the socket
        return found

    async def _read(self, within: float) -> None:
        try:
            message = await self.ws.receive(timeout=within)
        except TimeoutError:
            return
        if message.type != aiohttp.WSMsgType.TEXT:
            raise AssertionError(f"socket closed or not text: {message.type} {message.data}")
        self.raw.append(message.data)
        self.received.append(json.loads(message.data))

    async def op(self, op: str, **fields: Any) -> dict[str, Any]:
        return await self.expect(
            lambda m: m.get("op") == op and all(m.get(k) == v for k, v in fields.items()),
            TIMEOUT, f"{op} {fields}")

    async def count(self, op: str, n: int) -> list[dict[str, Any]]:
        """Wait until ``n`` messages of ``op`` have arrived; all of them."""
        def matching() -> list[dict[str, Any]]:
            return [m for m in self.received if m.get("op") == op]
        await self.expect(lambda m: len(matching()) >= n, what=f"{n} {op} messages")
        return matching()

    async def call(self, service: str, args: Any = None, rid: str = "") -> dict[str, Any]:
        self.calls += 1
        rid = rid or f"call-{self.calls}"
        frame: dict[str, Any] = {"op": "call_service", "service": service, "id": rid}
        if args is not None:
            frame["args"] = args
        await self.send(**frame)
        return await self.op("service_response", id=rid)

    def published(self, topic: str) -> list[dict[str, Any]]:
        return [m["msg"] for m in self.received if m.get("op") == "publish"
                and m.get("topic") == topic]


@asynccontextmanager
async def connect(url: str, **kw: Any) -> AsyncIterator[Client]:
    async with aiohttp.ClientSession() as session, session.ws_connect(url, **kw) as ws:
        yield Client(ws)


async def upgrade_status(url: str, **headers: str) -> int:
    """The HTTP status of a WebSocket upgrade to ``url`` (101 when it is accepted)."""
    async with aiohttp.ClientSession() as session:
        try:
            async with session.ws_connect(url, headers=headers):
                return 101
        except aiohttp.WSServerHandshakeError as exc:
            return exc.status


def bridge(robot: InProcessDaemon) -> Any:
    """The rosbridge server component of the daemon."""
    return robot.component("rosbridge")


class FakeScan:
    """A LaserScan stand-in with an infinite and a NaN range."""

    stamp = 1700000000.25
    frame_id = "laser"
    angle_min, angle_max, angle_increment = -math.pi, math.pi, math.radians(1)
    time_increment, scan_time, range_min, range_max = 0.0, 0.1, 0.12, 12.0
    ranges = np.array([1.25, np.inf, np.nan, 0.98], dtype=np.float32)
    intensities = np.array([10, 0, 0, 12], dtype=np.float32)
