# Hostile clients (rosbridge floods, fragment games, a seeded fuzzer; idle sockets, slow headers
# and stalled downloads on either port) run in their own process.
from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import json
import os
import random
import socket
import sys
import time
from collections import Counter
from collections.abc import AsyncIterator, Callable
from typing import Any

import aiohttp

Frame = dict[str, Any]
OPS = ("advertise", "unadvertise", "publish", "subscribe", "unsubscribe", "call_service",
       "service_response", "advertise_service", "unadvertise_service", "set_level",
       "fragment")
COMMAND_TOPICS = ("/cmd_vel", "/stamped_cmd_vel", "/estop")
NICENESS = 10


@contextlib.asynccontextmanager
async def connections(url: str, count: int) -> AsyncIterator[list[aiohttp.ClientWebSocketResponse]]:
    async with aiohttp.ClientSession() as session, contextlib.AsyncExitStack() as stack:
        yield [await stack.enter_async_context(session.ws_connect(url, max_msg_size=0))
               for _ in range(count)]


async def barrier(ws: aiohttp.ClientWebSocketResponse, rid: str,
                  seen: Callable[[Frame], None] = lambda frame: None,
                  within_s: float = 60.0) -> None:
    """Call ``/rosapi/get_time`` and read until its answer: everything sent before is done.
    Asked again every half second (a client over its request rate is not heard)."""
    call = {"op": "call_service", "service": "/rosapi/get_time", "id": rid}
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        await ws.send_json(call)
        with contextlib.suppress(TimeoutError):
            if await answered(ws, rid, seen, min(0.5, deadline - time.monotonic())):
                return
    raise RuntimeError(f"no answer to {rid} within {within_s} s")


async def answered(ws: aiohttp.ClientWebSocketResponse, rid: str,
                   seen: Callable[[Frame], None], within_s: float) -> bool:
    t_end = time.monotonic() + within_s
    while (left := t_end - time.monotonic()) > 0:
        message = await ws.receive(timeout=left)
        if message.type != aiohttp.WSMsgType.TEXT:
            raise RuntimeError(f"socket closed waiting for {rid}: {message.type}")
        frame = json.loads(message.data)
        seen(frame)
        if frame.get("id") == rid and frame.get("op") == "service_response":
            return True
    return False


class Statuses:
    """Counts ``status`` errors by the config key they name (or their first words)."""

    def __init__(self) -> None:
        self.counts: Counter[str] = Counter()

    def __call__(self, frame: Frame) -> None:
        if frame.get("op") == "status":
            text = str(frame.get("msg", ""))
            key = text.split("[rosbridge] ", 1)[1].split(")")[0] if "[rosbridge] " in text \
                else " ".join(text.split()[:3])
            self.counts[key] += 1


# -- floods ----------------------------------------------------------------------------------


async def advertise_many(url: str, topics: int, per_client: int,
                         fragment_size: int) -> dict[str, Any]:
    """Advertise ``topics`` topics over as many clients as it takes, then ask one of them for
    ``/rosapi/topics_and_raw_types`` in fragments of ``fragment_size``."""
    statuses = Statuses()
    clients = -(-topics // per_client)
    async with connections(url, clients) as sockets:
        for c, ws in enumerate(sockets):
            for i in range(min(per_client, topics - c * per_client)):
                await ws.send_json({"op": "advertise", "topic": f"/flood/c{c}/t{i}",
                                    "type": "std_msgs/msg/String"})
            await barrier(ws, f"advertised-{c}", statuses)
        t0 = time.monotonic()
        answer = await fragmented_call(sockets[0], "/rosapi/topics_and_raw_types",
                                       fragment_size, statuses)
        answer["seconds"] = time.monotonic() - t0
    return {"clients": clients, "statuses": dict(statuses.counts), **answer}


async def fragmented_call(ws: aiohttp.ClientWebSocketResponse, service: str,
                          fragment_size: int, seen: Callable[[Frame], None]) -> dict[str, Any]:
    """One call answered in fragments; joins them and reports what came back."""
    await ws.send_json({"op": "call_service", "service": service, "id": "big",
                        "fragment_size": fragment_size})
    parts: dict[int, str] = {}
    total = None
    while total is None or len(parts) < total:
        frame = json.loads((await ws.receive(timeout=120)).data)
        seen(frame)
        if frame.get("op") == "fragment" and frame.get("id") == "big":
            parts[frame["num"]] = frame["data"]
            total = frame["total"]
        elif frame.get("op") == "service_response" and frame.get("id") == "big":
            return {"fragments": 0, "answer": frame}
    joined = json.loads("".join(parts[i] for i in range(total)))
    values = joined.get("values", {})
    return {"fragments": total, "answer_topics": len(values.get("topics", [])),
            "result": joined.get("result")}


def subscribe_frame(rng: random.Random, n: int) -> Frame:
    """Subscriptions of every shape: one topic under many ids, many relay topics."""
    if n % 2:
        return {"op": "subscribe", "topic": "/odom", "id": f"s{n}",
                "throttle_rate": rng.choice([0, 10, 100]), "queue_length": rng.choice([0, 1, 5])}
    return {"op": "subscribe", "topic": f"/flood/sub{n}", "type": "std_msgs/msg/String",
            "id": f"s{n}"}


async def subscribe_flood(url: str, count: int, seconds: float) -> dict[str, Any]:
    """``count`` subscribe ops as fast as the socket takes them, then wait until the server
    has answered them all; or, given ``seconds``, subscribe and unsubscribe for that long and
    leave (the server drains what is buffered at its own pace)."""
    rng, statuses, sent = random.Random(1), Statuses(), 0
    async with connections(url, 1) as (ws,):
        reader = asyncio.create_task(drain(ws, statuses))
        t_end = time.monotonic() + seconds
        while sent < count or time.monotonic() < t_end:
            await ws.send_json(subscribe_frame(rng, sent))
            if seconds and sent % 3 == 2:
                await ws.send_json({"op": "unsubscribe", "topic": "/odom"})
            sent += 1
            if sent % 256 == 0:
                await asyncio.sleep(0)
        reader.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reader
        t0 = time.monotonic()
        if not seconds:
            await barrier(ws, "flooded", statuses, within_s=120)
        waited = time.monotonic() - t0
    return {"sent": sent, "statuses": dict(statuses.counts), "answered_after_s": waited}


async def drain(ws: aiohttp.ClientWebSocketResponse, seen: Callable[[Frame], None]) -> None:
    async for message in ws:
        if message.type == aiohttp.WSMsgType.TEXT:
            seen(json.loads(message.data))


async def scan_subscribers(url: str, clients: int, seconds: float,
                           fragment_size: int) -> dict[str, Any]:
    """``clients`` subscribers of /scan with ``fragment_size``, joining what they get."""
    whole = [0] * clients

    async def read(index: int, ws: aiohttp.ClientWebSocketResponse) -> None:
        parts: dict[str, dict[int, str]] = {}
        async for message in ws:
            frame = json.loads(message.data)
            if frame.get("op") == "publish":
                whole[index] += 1
            elif frame.get("op") == "fragment":
                pieces = parts.setdefault(frame["id"], {})
                pieces[frame["num"]] = frame["data"]
                if len(pieces) == frame["total"]:
                    joined = json.loads("".join(pieces[i] for i in range(frame["total"])))
                    whole[index] += joined.get("topic") == "/scan"
                    del parts[frame["id"]]

    async with connections(url, clients) as sockets:
        for ws in sockets:
            await ws.send_json({"op": "subscribe", "topic": "/scan",
                                "fragment_size": fragment_size})
        readers = [asyncio.create_task(read(i, ws)) for i, ws in enumerate(sockets)]
        await asyncio.sleep(seconds)
        for task in readers:
            task.cancel()
    return {"scans": whole}


def long_name_frame(n: int, chars: int) -> str:
    """A subscribe, advertise, publish or call_service naming a topic or service of ``chars``
    characters that looks valid (``/a/a/a...``)."""
    name = "/a" * (chars // 2)
    op = ("subscribe", "advertise", "publish", "call_service")[n % 4]
    frame: Frame = {"op": op, "id": f"long{n}", "type": "std_msgs/msg/String"}
    frame["service" if op == "call_service" else "topic"] = name
    if op == "publish":
        frame["msg"] = {"data": "x"}
    return json.dumps(frame)


async def long_names(url: str, clients: int, frames: int, chars: int) -> dict[str, Any]:
    """``clients`` clients each send ``frames`` frames with names of ``chars`` characters,
    each followed by a barrier (so every frame is handled before the next one goes out); a
    client that is closed for one connects again."""
    statuses, closes = Statuses(), Counter[str]()

    async def one(index: int) -> None:
        async with aiohttp.ClientSession() as session:
            ws: aiohttp.ClientWebSocketResponse | None = None
            for n in range(frames):
                if ws is None or ws.closed:
                    ws = await session.ws_connect(url, max_msg_size=0)
                try:
                    await ws.send_str(long_name_frame(index * frames + n, chars))
                    await barrier(ws, f"long-{index}-{n}", statuses)
                except (RuntimeError, ConnectionError, aiohttp.ClientError):
                    closes[str(ws.close_code)] += 1
                    await ws.close()
            if ws is not None:
                await ws.close()

    await asyncio.gather(*(one(i) for i in range(clients)))
    return {"frames": clients * frames, "statuses": dict(statuses.counts),
            "closes": dict(closes)}


# -- sockets that hold a slot: idle, dripping headers, reading nothing ---------------------------


def host_port(url: str) -> tuple[str, int]:
    host, port = url.split("//", 1)[1].split("/", 1)[0].rsplit(":", 1)
    return host, int(port)


async def _held_until_closed(reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                             drip: bytes, every_s: float, closed: list[float],
                             t0: float) -> None:
    """Hold one connection, writing ``drip`` a byte at a time; note when the server closed."""
    with contextlib.suppress(OSError):
        for byte in drip:
            writer.write(bytes([byte]))
            with contextlib.suppress(TimeoutError):
                if await asyncio.wait_for(reader.read(65536), every_s) == b"":
                    break
        else:
            while await reader.read(65536):
                pass
    closed.append(time.monotonic() - t0)
    writer.close()


async def idle_sockets(url: str, count: int, seconds: float, drip: bool) -> dict[str, Any]:
    """``count`` connections to the port of ``url`` that send nothing or, with ``drip``, a
    WebSocket upgrade request one byte every 0.5 s (slowloris); after ``seconds``, how many the
    server had closed and when."""
    host, port = host_port(url)
    key = base64.b64encode(os.urandom(16)).decode()
    request = (f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
               f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
               f"Sec-WebSocket-Version: 13\r\n\r\n").encode() if drip else b""
    closed: list[float] = []
    tasks, refused, t0 = [], 0, time.monotonic()
    for _ in range(count):
        try:
            reader, writer = await asyncio.open_connection(host, port)
        except OSError:
            refused += 1
            continue
        tasks.append(asyncio.create_task(
            _held_until_closed(reader, writer, request, 0.5, closed, t0)))
    await asyncio.wait(tasks, timeout=max(0.0, seconds - (time.monotonic() - t0)))
    for task in tasks:
        task.cancel()
    return {"opened": len(tasks), "refused": refused, "closed_by_server": len(closed),
            "last_closed_after_s": round(max(closed, default=0.0), 2)}


async def stalled_readers(url: str, count: int, seconds: float) -> dict[str, Any]:
    """``count`` clients that GET ``url`` (a download) with a small receive window, read the
    answer's first bytes and then nothing; after ``seconds``, what they were answered and how
    many the server had cut off (reset: a server that gives up on a reader drops its data)."""
    host, port = host_port(url)
    path = "/" + url.split("//", 1)[1].split("/", 1)[1]
    loop = asyncio.get_running_loop()
    answers: Counter[str] = Counter()
    held: list[socket.socket] = []
    for _ in range(count):
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # before connect
        sock.setblocking(False)
        try:
            async with asyncio.timeout(5.0):
                await loop.sock_connect(sock, (host, port))
                await loop.sock_sendall(sock, f"GET {path} HTTP/1.1\r\nHost: {host}:{port}"
                                        "\r\n\r\n".encode())
                head = await loop.sock_recv(sock, 64)
        except (OSError, TimeoutError):
            answers["refused"] += 1
            sock.close()
            continue
        answers[head.split(b" ")[1].decode() if head.startswith(b"HTTP/") else "closed"] += 1
        held.append(sock)
    t0, cut = time.monotonic(), dict[int, float]()
    while len(cut) < len(held) and time.monotonic() - t0 < seconds:
        for index, sock in enumerate(held):
            if index not in cut and sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR):
                cut[index] = time.monotonic() - t0
        await asyncio.sleep(0.1)
    for sock in held:
        sock.close()
    return {"answers": dict(answers), "held": len(held), "cut_off_by_server": len(cut),
            "last_cut_off_after_s": round(max(cut.values(), default=0.0), 2)}


# -- the fuzzer ------------------------------------------------------------------------------

JUNK_VALUES: list[Any] = [None, True, -1, 0, 2**63, -(2**63), 10**400, 1e308, -0.0, 1.5, "",
                          "x" * 300, "\u0000", "😀" * 50, [], [1, [2, [3]]], {}, {"a": {}},
                          "/cmd_vel", "cmd_vel", "//", "/a b", "../x"]


def junk(rng: random.Random) -> Any:
    return rng.choice(JUNK_VALUES)


def fuzz_json(rng: random.Random) -> str:
    depth = rng.choice([10, 1000, 5000])
    return rng.choice([
        "{not json", "", " ", "[]", "null", '"op"', "1" * 400, '{"op": NaN}',
        "[" * depth + "]" * depth, '{"op":"publish","topic":"/x","msg":' + "{\"a\":" * depth
        + "1" + "}" * depth + "}", '{"op":"subscribe","topic":"/odom"', "\ufffd" * 10,
        json.dumps({"op": "subscribe", "topic": "/odom", "queue_length": 2**63}),
        '{"op":"publish","topic":"/cmd_vel","msg":{"linear":{"x":' + "9" * 400 + "}}}",
    ])


def fuzz_fields(rng: random.Random) -> str:
    frame: Frame = {"op": rng.choice(OPS)}
    for key in rng.sample(["id", "topic", "service", "type", "msg", "args", "values", "result",
                           "throttle_rate", "queue_length", "fragment_size", "compression",
                           "latch", "level", "timeout", "data", "num", "total"],
                          rng.randint(0, 6)):
        frame[key] = junk(rng)
    return json.dumps(frame)


def fuzz_commands(rng: random.Random) -> str:
    topic = rng.choice(COMMAND_TOPICS)
    value = rng.choice([0.3, -1.0, 1e9, float("nan"), "fast", None])
    msgs = {"/cmd_vel": {"linear": {"x": value}, "angular": {"z": 0.5}},
            "/estop": {"data": rng.choice([True, False, "no"])},
            "/stamped_cmd_vel": {"data": json.dumps({"linear": {"x": 0.3}, "t_sent": 1})}}
    op = rng.choice(["publish", "publish", "advertise"])
    frame: Frame = {"op": op, "topic": topic, "id": rng.randint(0, 99)}
    if op == "publish":
        frame["msg"] = msgs[topic]
    else:
        frame["type"] = {"/cmd_vel": "geometry_msgs/Twist", "/estop": "std_msgs/Bool"}.get(
            topic, "std_msgs/String")
    return json.dumps(frame)  # NaN goes out as the invalid JSON token NaN


def fuzz_fragments(rng: random.Random) -> str:
    total = rng.choice([1, 2, 3, 1000, 10**6, 2**40])
    data = rng.choice(["", "😀" * rng.choice([1, 1000, 100_000]), "{", "x" * 1000])
    return json.dumps({"op": "fragment", "id": f"f{rng.randint(0, 20)}", "data": data,
                       "num": rng.randint(0, 3), "total": total})


def fuzz_subscriptions(rng: random.Random) -> str:
    n = rng.randint(0, 5000)
    if rng.random() < 0.3:
        return json.dumps({"op": "unsubscribe", "topic": rng.choice(["/odom", f"/r{n}"]),
                           "id": f"s{n}"})
    return json.dumps({"op": "subscribe", "topic": rng.choice(["/odom", "/scan", f"/r{n}"]),
                       "type": rng.choice([None, "std_msgs/String"]), "id": f"s{n}",
                       "throttle_rate": rng.choice([0, 1, 1e12]),
                       "queue_length": rng.choice([0, 1, 100, 10**6]),
                       "fragment_size": rng.choice([None, 1, 7, 2**31])})


def fuzz_services(rng: random.Random) -> str:
    service = rng.choice(["/rosapi/topics_and_raw_types", "rosapi/topics", "/fz", "/add",
                          "/rosapi/node_details"])
    op = rng.choice(["call_service", "call_service", "advertise_service", "service_response",
                     "unadvertise_service"])
    return json.dumps({"op": op, "service": service, "type": "x/Y", "id": rng.randint(0, 9),
                       "args": junk(rng), "fragment_size": rng.choice([None, 1, 50]),
                       "timeout": rng.choice([None, 0.01, 1e9]), "result": True,
                       "values": junk(rng)})


def fuzz_names(rng: random.Random) -> str:
    """Over-long or odd names in a field that names something (topic, service, type, op,
    id): just over the 256-character limit, a few KiB, just under and far over the frame
    limit of a client without the token (16 KiB)."""
    length = rng.choice([257, 4096, 15_000, 100_000])
    name = rng.choice(["/a" * (length // 2), "a" * length, "/" + "é" * length])
    frame: Frame = {"op": rng.choice(OPS), "topic": "/x", "service": "/s",
                    "type": "std_msgs/String", "id": rng.randint(0, 9)}
    frame[rng.choice(["topic", "service", "type", "op", "id"])] = name
    return json.dumps(frame)


def fuzz_binary(rng: random.Random) -> bytes:
    return rng.randbytes(rng.randint(0, 2000))


TEXT_CATEGORIES: dict[str, Callable[[random.Random], str]] = {
    "json": fuzz_json, "fields": fuzz_fields, "commands": fuzz_commands,
    "fragments": fuzz_fragments, "subscriptions": fuzz_subscriptions, "services": fuzz_services,
    "names": fuzz_names,
}


def wire_junk(rng: random.Random) -> bytes:
    """One WebSocket frame a client must never send (raw bytes after the handshake)."""
    mask = b"\0\0\0\0"
    return rng.choice([
        bytes([0x81, 0x82]) + mask + b"\xff\xfe",  # invalid UTF-8 text
        bytes([0x83, 0x80]) + mask,  # reserved opcode
        bytes([0xC1, 0x82]) + mask + b"{}",  # reserved bits
        bytes([0x81, 0x02]) + b"{}",  # unmasked
        bytes([0x89, 0xFE, 0x01, 0x00]) + mask + b"x" * 256,  # control frame too long
        bytes([0x81, 0xFF]) + (2**62).to_bytes(8, "big") + mask,  # absurd length
    ])


async def wire_attempt(host: str, port: int, payload: bytes) -> None:
    reader, writer = await asyncio.open_connection(host, port)
    key = base64.b64encode(os.urandom(16)).decode()
    writer.write(f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: "
                 f"Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
                 .encode() + payload)
    with contextlib.suppress(Exception):
        await asyncio.wait_for(reader.read(4096), 2.0)
    writer.close()
    with contextlib.suppress(Exception):
        await writer.wait_closed()


class Fuzzer:
    """``workers`` tokenless clients sending seeded junk round-robin over the categories."""

    def __init__(self, url: str, seed: int, workers: int,
                 categories: list[str] | None = None) -> None:
        self.url = url
        self.seed = seed
        self.workers = workers
        self.categories = categories or [*TEXT_CATEGORIES, "binary", "wire"]
        self.sent: Counter[str] = Counter()
        self.replies: Counter[str] = Counter()
        self.reconnects = 0

    async def run(self, seconds: float) -> dict[str, Any]:
        t_end = time.monotonic() + seconds
        names = [c for c in self.categories if c != "wire"]
        workers = [self._worker(i, t_end, names) for i in range(self.workers if names else 0)]
        wire = [self._wire(t_end)] if "wire" in self.categories else []
        await asyncio.gather(*workers, *wire)
        return {"inputs": dict(self.sent), "replies": dict(self.replies),
                "reconnects": self.reconnects, "total_inputs": sum(self.sent.values())}

    async def _worker(self, index: int, t_end: float, names: list[str]) -> None:
        rng = random.Random(self.seed * 1000 + index)
        async with aiohttp.ClientSession() as session:
            while time.monotonic() < t_end:
                with contextlib.suppress(aiohttp.ClientError, ConnectionError, RuntimeError):
                    async with session.ws_connect(self.url, max_msg_size=0) as ws:
                        reader = asyncio.create_task(self._count(ws))
                        await self._send_until(ws, rng, names, t_end)
                        reader.cancel()
                self.reconnects += 1

    async def _send_until(self, ws: aiohttp.ClientWebSocketResponse, rng: random.Random,
                          names: list[str], t_end: float) -> None:
        while time.monotonic() < t_end and not ws.closed:
            category = rng.choice(names)
            if category == "binary":
                await ws.send_bytes(fuzz_binary(rng))
            else:
                await ws.send_str(TEXT_CATEGORIES[category](rng))
            self.sent[category] += 1
            await asyncio.sleep(0.0005)

    async def _count(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        async for message in ws:
            if message.type == aiohttp.WSMsgType.TEXT:
                self.replies[str(json.loads(message.data).get("op"))] += 1

    async def _wire(self, t_end: float) -> None:
        rng = random.Random(self.seed)
        host, port = self.url.split("//", 1)[1].rstrip("/").rsplit(":", 1)
        while time.monotonic() < t_end:
            with contextlib.suppress(OSError, TimeoutError):
                await wire_attempt(host, int(port), wire_junk(rng))
            self.sent["wire"] += 1
            await asyncio.sleep(0.05)


# -- the worker command line -------------------------------------------------------------------


# attack => its numeric options: (flag, type, default)
ATTACK_OPTIONS: dict[str, list[tuple[str, type, float]]] = {
    "advertise-many": [("--topics", int, 1500), ("--per-client", int, 100),
                       ("--fragment-size", int, 1)],
    "subscribe-flood": [("--count", int, 10_000), ("--seconds", float, 0.0)],
    "scan-subscribers": [("--clients", int, 3), ("--seconds", float, 3.0),
                         ("--fragment-size", int, 1)],
    "long-names": [("--clients", int, 8), ("--frames", int, 4), ("--chars", int, 1_048_000)],
    "idle-sockets": [("--count", int, 300), ("--seconds", float, 20.0), ("--drip", int, 0)],
    "stalled-readers": [("--count", int, 260), ("--seconds", float, 30.0)],
    "fuzz": [("--seconds", float, 10.0), ("--seed", int, 1), ("--workers", int, 4)],
}


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="python -m daemon.bench.rosbridge_attacks")
    top.add_argument("--url", required=True)
    sub = top.add_subparsers(dest="attack", required=True)
    for name, options in ATTACK_OPTIONS.items():
        attack_parser = sub.add_parser(name)
        for flag, kind, default in options:
            attack_parser.add_argument(flag, type=kind, default=kind(default))
    sub.choices["fuzz"].add_argument("--only", action="append",
                                     help="fuzz only this category (repeatable)",
                                     choices=[*TEXT_CATEGORIES, "binary", "wire"])
    return top


async def attack(args: argparse.Namespace) -> dict[str, Any]:
    if args.attack == "advertise-many":
        return await advertise_many(args.url, args.topics, args.per_client, args.fragment_size)
    if args.attack == "subscribe-flood":
        return await subscribe_flood(args.url, args.count, args.seconds)
    if args.attack == "idle-sockets":
        return await idle_sockets(args.url, args.count, args.seconds, bool(args.drip))
    if args.attack == "stalled-readers":
        return await stalled_readers(args.url, args.count, args.seconds)
    if args.attack == "long-names":
        return await long_names(args.url, args.clients, args.frames, args.chars)
    if args.attack == "scan-subscribers":
        return await scan_subscribers(args.url, args.clients, args.seconds, args.fragment_size)
    return await Fuzzer(args.url, args.seed, args.workers, args.only).run(args.seconds)


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    # hostile clients are other machines; sharing this one's cores, they yield to the daemon
    # so that what is measured is the protocol's cost, not CPU time taken by the attacker
    os.nice(NICENESS)
    print(json.dumps(asyncio.run(attack(args))), flush=True)
    return 0


async def run_attack(url: str, *args: str) -> dict[str, Any]:
    """Run one attack in a separate process (the daemon's loop stays the daemon's alone)."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "daemon.bench.rosbridge_attacks", "--url", url, *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    out, err = await proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"attack {args[0]} failed: {err.decode()[-3000:]}")
    return dict(json.loads(out.decode().strip().splitlines()[-1]))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
