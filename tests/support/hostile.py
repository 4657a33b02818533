# The hostile corpus, thrown at every declared HTTP route and incoming topic by the contract test.
from __future__ import annotations

import asyncio
import json
import re
import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import aiohttp

from daemon.messages.msgtypes import get_type

LOCAL = "127.0.0.1"
HUGE = 1e308

#: values tried for each ``{placeholder}`` of a route's path: plain, traversal, odd bytes,
#: long, and the names of the big files the test puts in the directories the daemon serves
PATH_VALUES = ("x", "..", "%2e%2e%2fetc%2fpasswd", "a%00b", "b" * 300)

#: the body corpus: every key a route might read, with hostile values
_HUGE_FIELDS = {"x": HUGE, "y": -HUGE, "theta": HUGE, "yaw": HUGE, "size": HUGE,
                "linear": {"x": HUGE, "y": 0, "z": 0}, "angular": {"x": 0, "y": 0, "z": HUGE},
                "engaged": HUGE, "enabled": HUGE, "name": HUGE, "mode": HUGE, "frame": HUGE,
                "steps": [{"x": HUGE, "y": HUGE}], "waypoints": [[HUGE, -HUGE]],
                "object": [HUGE, 0], "drop": [0, HUGE], "pose": {"x": HUGE, "y": HUGE},
                "joints": {"shoulder": HUGE}, "objects": [{"x": HUGE, "y": HUGE}]}
#: bodies whose every field would be valid but one (so the refusal comes from deep inside)
_ONE_HOSTILE: list[dict[str, Any]] = [
    {"x": 0.5, "y": HUGE}, {"x": -HUGE, "y": 0.5}, {"x": 0.5, "y": 0.5, "theta": HUGE},
    {"x": 0.5, "y": 0.5, "heading_deg": HUGE}, {"x": 9000.0, "y": 0.0},
    {"waypoints": [[0.5, 0.5], [HUGE, 0.0]]}, {"path": "figure_eight", "size": HUGE},
    {"steps": [{"x": 0.5, "y": 0.5}, {"x": HUGE, "y": 0.0}]},
    {"object": [0.5, 0.5], "drop": [HUGE, 0.0]}, {"object": [HUGE, 0.5], "drop": [0.0, 0.0]},
    {"linear": {"x": HUGE, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}},
    {"linear": {"x": 0.0, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": -HUGE}},
    {"name": "lab", "pose": {"x": HUGE, "y": 0.0, "theta": 0.0}},
    {"objects": [{"x": HUGE, "y": 0.0, "radius": 0.1}]}]
_WRONG_TYPES: dict[str, Any] = {key: ("1" if not isinstance(value, str) else 1)
                for key, value in _HUGE_FIELDS.items()}
_WRONG_TYPES.update({"linear": "fast", "steps": "many", "waypoints": {"a": 1}})
BODIES: dict[str, bytes] = {
    "no body": b"",
    "empty object (fields missing)": b"{}",
    "array": b"[]",
    "string": b'"text"',
    "unknown field": b'{"unknown": 1}',
    "1e308 everywhere": json.dumps(_HUGE_FIELDS).encode(),
    **{f"1e308 alone in {key}": json.dumps({key: value}).encode()
       for key, value in _HUGE_FIELDS.items()},
    **{f"one field 1e308 of {i}": json.dumps(body).encode()
       for i, body in enumerate(_ONE_HOSTILE)},
    "NaN": b'{"x": NaN, "y": 0}',
    "+inf": b'{"x": Infinity, "linear": {"x": Infinity}}',
    "-inf": b'{"x": -Infinity, "angular": {"z": -Infinity}}',
    "wrong types": json.dumps(_WRONG_TYPES).encode(),
    "unknown frame": b'{"frame": "nowhere", "x": 0.0, "y": 0.0, '
                     b'"header": {"frame_id": "nowhere"}}',
    "deep nesting": b"[" * 5000 + b"]" * 5000,
    "oversized": b'{"x": "' + b"a" * (1024 * 1024 + 16) + b'"}',
}
TOKENS: dict[str, str | None] = {"no token": None, "wrong token": "not-the-token-0"}


@dataclass
class Findings:
    """What broke the contract, by route or topic and case; and what was covered."""

    problems: list[str] = field(default_factory=list)
    requests: int = 0
    routes: set[str] = field(default_factory=set)
    topics: set[str] = field(default_factory=set)
    #: what is being tried now (the loop canary names it with a stall)
    current: str = ""
    #: components whose health was "error" before the run (not the corpus's doing)
    broken: set[str] = field(default_factory=set)

    def add(self, where: str, case: str, what: str) -> None:
        if len(self.problems) < 200:
            self.problems.append(f"{where} [{case}]: {what}")


def concrete_paths(path: str) -> list[str]:
    """Request paths for a route pattern: each placeholder filled with each of PATH_VALUES."""
    if "{" not in path:
        return [path]
    return [re.sub(r"\{[^}]+\}", value, path) for value in PATH_VALUES]


def bodies_for(method: str) -> dict[str, bytes]:
    return BODIES if method in ("POST", "PUT", "PATCH", "DELETE") else {"no body": b""}


async def hammer_route(session: aiohttp.ClientSession, base_url: str, method: str,
                       path: str, token: str, findings: Findings) -> None:
    """Every body of the corpus, with no token, a wrong one and the right one, at every
    concrete path of one route: no 5xx, no traceback, answered within 15 s."""
    findings.routes.add(f"{method} {path}")
    tokens = {**TOKENS, "right token": token}
    for concrete in concrete_paths(path):
        for case, body in bodies_for(method).items():
            for who, offered in tokens.items():
                headers = {"Content-Type": "application/json"} if body else {}
                if offered:
                    headers["Authorization"] = f"Bearer {offered}"
                await _one(session, base_url, method, concrete, body, headers,
                           f"{case}, {who}", findings)


async def _one(session: aiohttp.ClientSession, base_url: str, method: str, path: str,
               body: bytes, headers: dict[str, str], case: str, findings: Findings) -> None:
    findings.requests += 1
    where = f"{method} {path[:60]}"
    findings.current = f"{where} [{case}]"
    try:
        async with asyncio.timeout(15), session.request(
                method, base_url + path, data=body or None, headers=headers) as answer:
            text = (await answer.content.read(65536)).decode("utf-8", "replace")
            if answer.status >= 500:
                findings.add(where, case, f"{answer.status}: {text[:200]}")
            if case.endswith("right token") and answer.status in (401, 429):
                findings.add(where, case, f"the right token refused: {answer.status}")
            if "Traceback" in text:
                findings.add(where, case, "a traceback in the answer")
    except TimeoutError:
        findings.add(where, case, "no answer within 15 s")
    except (aiohttp.ClientError, ConnectionError) as exc:
        if "oversized" not in case:  # a server may close on an oversized body: allowed
            findings.add(where, case, f"connection error: {exc!r}")


async def never_reading(port: int, method: str, path: str, token: str,
                        count: int) -> list[socket.socket]:
    """``count`` clients that send one request with the token and never read the answer."""
    loop = asyncio.get_running_loop()
    clients = []
    request = (f"{method} {path} HTTP/1.1\r\nHost: {LOCAL}:{port}\r\n"
               f"Authorization: Bearer {token}\r\nContent-Length: 0\r\n\r\n").encode()
    for _ in range(count):
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        sock.setblocking(False)
        await loop.sock_connect(sock, (LOCAL, port))
        await loop.sock_sendall(sock, request)
        clients.append(sock)
    return clients


# -- topics -----------------------------------------------------------------------------------

def _filled(type_name: str, number: Any, text: Any, depth: int = 0) -> dict[str, Any]:
    """A message of ``type_name`` with every number ``number`` and every string ``text``."""
    out: dict[str, Any] = {}
    for f in get_type(type_name).fields:
        base = f.base
        if base in ("string", "wstring"):
            value: Any = text
        elif base == "bool":
            value = number if not isinstance(number, float) else True
        elif "/" in base:
            if depth > 6:
                continue
            value = _filled(_qualified(base), number, text, depth + 1)
        else:
            value = number
        out[f.name] = [value] * 3 if f.is_array and f.length is None else (
            [value] * f.length if f.is_array and f.length else value)
    return out


def _qualified(base: str) -> str:
    return base if "/msg/" in base else base.replace("/", "/msg/", 1)


def topic_corpus(type_name: str) -> Iterator[tuple[str, Any]]:
    """(case, the msg value) for a topic of ``type_name``; NaN and ±inf as raw JSON text."""
    yield "empty (fields missing)", {}
    yield "1e308 everywhere", _filled(type_name, HUGE, "x")
    yield "-1e308 everywhere", _filled(type_name, -HUGE, "x")
    yield "huge integers", _filled(type_name, 10**30, "x")
    yield "wrong types", _filled(type_name, "1", 1)
    yield "unknown frame", _filled(type_name, 0.0, "nowhere")
    yield "not an object", [1, 2, 3]
    yield "oversized", {"data": "a" * (2 * 1024 * 1024)}
    for raw in ("NaN", "Infinity", "-Infinity"):
        yield raw, raw  # spliced into the frame as it is


def publish_frame(topic: str, type_name: str, msg: Any) -> str:
    if isinstance(msg, str) and msg in ("NaN", "Infinity", "-Infinity"):
        value = json.dumps(_filled(type_name, 0.0, "x")).replace("0.0", msg)
        return f'{{"op": "publish", "topic": "{topic}", "msg": {value}}}'
    return json.dumps({"op": "publish", "topic": topic, "type": type_name, "msg": msg})


class LoopCanary:
    """The longest the event loop went without running a 10 ms timer (s): a stall of the
    loop the daemon shares with the test; ``during``: what was being tried then."""

    def __init__(self, findings: Findings) -> None:
        self.findings = findings
        self.worst = 0.0
        self.during = ""
        self._task: asyncio.Task[None] | None = None

    async def _run(self) -> None:
        last = time.monotonic()
        while True:
            await asyncio.sleep(0.01)
            now = time.monotonic()
            if now - last - 0.01 > self.worst:
                self.worst, self.during = now - last - 0.01, self.findings.current
            last = now

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._run())

    def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
