# A Foxglove WebSocket protocol client for tests: connects, remembers ops and messages by channel.
from __future__ import annotations

import json
import struct
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

import aiohttp

from tests.support.wait import Deadline

TIMEOUT = 10.0
SUBPROTOCOL = "foxglove.websocket.v1"


class FoxgloveClient:
    """Text ops as received, binary message data by subscription id, and time frames."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.ops: list[dict[str, Any]] = []
        self.messages: dict[int, list[tuple[int, bytes]]] = {}
        self.times: list[int] = []
        self.closed = False

    async def send(self, **frame: Any) -> None:
        await self.ws.send_str(json.dumps(frame))

    async def read(self, within: float) -> None:
        try:
            message = await self.ws.receive(timeout=within)
        except TimeoutError:
            return
        if message.type == aiohttp.WSMsgType.TEXT:
            self.ops.append(json.loads(message.data))
        elif message.type == aiohttp.WSMsgType.BINARY:
            data = message.data
            if data[0] == 1:
                sub_id, t_ns = struct.unpack_from("<IQ", data, 1)
                self.messages.setdefault(sub_id, []).append((t_ns, data[13:]))
            elif data[0] == 2:
                self.times.append(struct.unpack_from("<Q", data, 1)[0])
        else:
            self.closed = True

    async def until(self, done: Callable[[], Any], what: str,
                    within: float = TIMEOUT) -> Any:
        deadline = Deadline(lambda: f"{what}; ops {[o.get('op') for o in self.ops[-10:]]}",
                            within)
        while not (found := done()):
            deadline.check()
            if self.closed:
                raise AssertionError(f"{what}: the server closed the connection")
            await self.read(deadline.remaining())
        return found

    async def op(self, name: str, what: str = "", within: float = TIMEOUT,
                 where: Callable[[dict[str, Any]], bool] = lambda o: True) -> dict[str, Any]:
        found: dict[str, Any] = await self.until(
            lambda: next((o for o in self.ops if o.get("op") == name and where(o)), None),
            what or f"a {name} op", within)
        return found

    async def channels(self) -> dict[str, dict[str, Any]]:
        advertise = await self.op("advertise")
        return {c["topic"]: c for c in advertise["channels"]}

    async def statuses(self, within: float) -> list[dict[str, Any]]:
        """Status ops received within ``within`` seconds from now (waits them out)."""
        end = time.monotonic() + within
        while (left := end - time.monotonic()) > 0 and not self.closed:
            await self.read(left)
        return [o for o in self.ops if o.get("op") == "status"]


def publish_frame(channel_id: int, payload: bytes) -> bytes:
    return struct.pack("<BI", 1, channel_id) + payload


@asynccontextmanager
async def connect(url: str, headers: dict[str, str] | None = None,
                  protocols: tuple[str, ...] = (SUBPROTOCOL,)) -> AsyncIterator[FoxgloveClient]:
    async with aiohttp.ClientSession() as session, session.ws_connect(
            url, protocols=protocols, headers=headers or {}, max_msg_size=0) as ws:
        yield FoxgloveClient(ws)


async def upgrade_status(url: str, headers: dict[str, str] | None = None,
                         protocols: tuple[str, ...] = (SUBPROTOCOL,)) -> int:
    """The HTTP status of an upgrade attempt (101 when it is accepted)."""
    try:
        async with connect(url, headers, protocols):
            return 101
    except aiohttp.WSServerHandshakeError as exc:
        return exc.status
