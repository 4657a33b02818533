# Seeded HTTP fuzz and load against a real daemon: no 5xx, JSON errors, nothing moves, memory flat.
from __future__ import annotations

import asyncio
import json
import os
import random
import re
import time
import zlib
from collections import Counter
from collections.abc import Callable
from typing import Any

import pytest

from daemon.bench.rosbridge_flood import MachineCanary
from tests.support.daemon_subprocess import StartDaemonSubprocess
from tests.support.http_raw import exchange, parse_answer, request, rss_kib, send_raw
from tests.support.rosbridge import stall_limit_ms

SEED = int(os.environ.get("ARBITERD_FUZZ_SEED", "1122"))
BUDGET_S = float(os.environ.get("ARBITERD_FUZZ_SECONDS", "36"))
PARALLEL = 48
TOKEN = "fuzz-token-never-sent"
READ_S = 2.5  # > the daemon's 1 s idle and body timeouts: every input gets an answer or a close

Input = tuple[list[bytes], float]  # TCP writes, pause between them
Generator = Callable[[random.Random, int], Input]

TEMPLATES = [
    ("GET", "/api/health", b""), ("GET", "/api/status", b""), ("GET", "/api/latency", b""),
    ("GET", "/metrics", b""), ("HEAD", "/api/robot_info", b""),
    ("POST", "/api/cmd_vel", b'{"linear": {"x": 0.3}, "angular": {"z": 0.5}, "id": 1}'),
    ("POST", "/api/estop", b'{"engaged": false}'), ("POST", "/api/estop", b'{"engaged": true}'),
]
DRIVE = ("/api/cmd_vel", "/api/estop")
HOSTS = ["127.0.0.1", "evil.example", "localhost:1", "[::1]", "[zz", "", "a" * 300,
         "127.0.0.1@evil.example", "xn--80ak6aa92e.com", "robot.local", "0", "::1"]
ORIGINS = ["http://evil.example", "null", "http://127.0.0.1", "http://127.0.0.1@evil",
           "javascript:x", "http://localhost:8080", "", "\u00e9"]
STATUS_LINE = re.compile(rb"HTTP/[01]\.[019] [1-5]\d\d ")  # a 0.9 request line gets 0.9
NOISE = [b"\r", b"\n", b"\x00", b" ", b":", b"\r\n", b"\r\n\r\n", b"\xff", b"%", b"\t", b"{",
         b"0\r\n\r\n"]


def template(rng: random.Random, port: int, **kw: Any) -> bytes:
    method, path, body = rng.choice(TEMPLATES)
    return request(method, path, port, body, **kw)


def random_bytes(rng: random.Random, port: int) -> Input:
    return [rng.randbytes(rng.randint(1, 400))], 0.0


def mutated(rng: random.Random, port: int) -> Input:
    data = bytearray(template(rng, port))
    for _ in range(rng.randint(1, 4)):
        data = data or bytearray(b"\r\n")
        at = rng.randrange(len(data))
        op = rng.randrange(5)
        if op == 0:
            data[at] = rng.randrange(256)
        elif op == 1:
            data[at:at] = rng.choice(NOISE) if rng.random() < 0.6 else rng.randbytes(8)
        elif op == 2:
            del data[at:at + rng.randint(1, 20)]
        elif op == 3:
            data[at:at] = data[at:at + rng.randint(1, 60)]
        else:
            del data[at:]
            data += b"\r\n\r\n"
    return [bytes(data)], 0.0


def json_value(rng: random.Random, depth: int = 0) -> Any:
    kind = rng.randrange(9 if depth < 6 else 6)
    scalars: list[Callable[[], Any]] = [
        lambda: rng.choice([0, -1, 1e308, -1e-308, 2 ** 63, rng.uniform(-1e3, 1e3)]),
        lambda: rng.choice([True, False, None]),
        lambda: "".join(chr(rng.randrange(0x20, 0x2FFF)) for _ in range(rng.randrange(12))),
        lambda: rng.choice(["linear", "angular", "x", "z", "engaged", "id", "t_sent"]),
        lambda: int("9" * rng.randint(1, 90)),
        lambda: rng.choice(["NaN", "Infinity", "-0"]),
    ]
    if kind < 6:
        return scalars[kind]()
    if kind == 6:
        return [json_value(rng, depth + 1) for _ in range(rng.randrange(4))]
    keys = ["linear", "angular", "x", "y", "z", "engaged", "reason", "id", "t_sent", "\u2603"]
    return {rng.choice(keys): json_value(rng, depth + 1) for _ in range(rng.randrange(5))}


def json_bodies(rng: random.Random, port: int) -> Input:
    """Tokenless (or wrong-token) bodies for the drive routes."""
    return _json_request(rng, port, rng.choice(DRIVE), {})


def json_commands(rng: random.Random, port: int) -> Input:
    """Bodies for ``/api/cmd_vel`` with the token, while the e-stop is latched: the parser and
    the validation see them, and the latch keeps any valid one from moving the robot."""
    return _json_request(rng, port, "/api/cmd_vel", {"Authorization": f"Bearer {TOKEN}"})


def _json_request(rng: random.Random, port: int, path: str, auth: dict[str, str]) -> Input:
    body = json.dumps(json_value(rng), ensure_ascii=rng.random() < 0.5).encode()
    if rng.random() < 0.2:
        body = body.replace(b'"', b"", rng.randint(1, 3))
    if rng.random() < 0.1:
        body = b"[" * rng.randint(30, 5000) + body
    headers = dict(auth)
    if not auth and rng.random() < 0.3:
        headers["Authorization"] = rng.choice(["Bearer wrong", "Bearer ", "Basic " + TOKEN[:4],
                                               "Bearer " + TOKEN[:-1]])
    if rng.random() < 0.2:
        headers["Content-Encoding"] = "deflate"
        body = zlib.compress(body)
        if rng.random() < 0.5:
            body = body[:rng.randrange(1, len(body))] + rng.randbytes(3)
    return [request("POST", path, port, body, headers=headers)], 0.0


def header_fuzz(rng: random.Random, port: int) -> Input:
    headers: dict[str, str] = {}
    for _ in range(rng.randint(1, 6)):
        name = rng.choice(["Origin", "Authorization", "Content-Length", "Transfer-Encoding",
                           "Expect", "Upgrade", "Connection", "Content-Type", "X-" + "a" *
                           rng.randrange(1, 50), "Cookie", "Accept-Encoding", "Range"])
        value = rng.choice([rng.choice(ORIGINS), str(rng.randint(-5, 10 ** 12)), "chunked",
                            "100-continue", "websocket", "upgrade, keep-alive",
                            "application/json; charset=latin-1", "deflate, gzip",
                            bytes(rng.randrange(0x20, 0x100) for _ in range(20)).decode(
                                "latin-1")])
        headers[name] = value
    return [template(rng, port, headers=headers, host=rng.choice(HOSTS))], 0.0


def method_path(rng: random.Random, port: int) -> Input:
    method = rng.choice(["GET", "POST", "PUT", "DELETE", "OPTIONS", "TRACE", "PATCH", "get",
                         "M-SEARCH", "X" * rng.randint(1, 40), "CONNECT"])
    segments = ["api", "cmd_vel", "..", "", "%2e%2e", "%00", "health", "\u00e9t\u00e9",
                "estop", "metrics", "a" * rng.randrange(1, 2000), "%ZZ", "?token=" + TOKEN[:3]]
    path = "/" + "/".join(rng.choice(segments) for _ in range(rng.randint(0, 5)))
    path += rng.choice(["", "?", "?token=x&token=y", "#frag", "?" + "q=" * 100])
    raw = f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
    return [raw.encode("utf-8")], 0.0


def delivery(rng: random.Random, port: int) -> Input:
    data = b"".join(template(rng, port).replace(b"Connection: close\r\n", b"")
                    for _ in range(rng.randint(1, 4)))
    cuts = sorted(rng.sample(range(1, len(data)), min(len(data) - 1, rng.randint(1, 6))))
    parts = [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]
    return parts, rng.choice([0.0, 0.001, 0.01, 0.05])


CATEGORIES: dict[str, Generator] = {
    "random bytes": random_bytes, "mutated requests": mutated, "JSON bodies": json_bodies,
    "JSON commands (token, e-stop latched)": json_commands,
    "headers": header_fuzz, "methods and paths": method_path, "split and pipelined": delivery,
}


class Findings:
    def __init__(self) -> None:
        self.tried: Counter[str] = Counter()
        self.statuses: dict[str, Counter[int]] = {name: Counter() for name in CATEGORIES}
        self.problems: list[str] = []
        #: health answered 503 because the control tick had stalled (judged against what the
        #: machine did meanwhile, at the end)
        self.stalls = 0

    def check(self, category: str, sent: list[bytes], answer: bytes) -> None:
        self.tried[category] += 1
        if not answer:
            self.statuses[category][0] += 1  # closed without an answer (e.g. idle timeout)
            return
        problem = _problem(answer, head=b"".join(sent).startswith(b"HEAD "))
        if problem and _stalled_health(answer):
            self.stalls += 1
            problem = None
        status = int(answer.split(b" ", 2)[1]) if STATUS_LINE.match(answer) else -1
        self.statuses[category][status] += 1
        if problem and len(self.problems) < 20:
            self.problems.append(f"{category}: {problem}: sent {b''.join(sent)[:160]!r}")


def _problem(answer: bytes, head: bool) -> str | None:
    if not STATUS_LINE.match(answer):
        return f"not an HTTP answer: {answer[:80]!r}"
    parsed = parse_answer(answer, head_only=head)
    if parsed is None:
        return f"incomplete answer: {answer[:120]!r}"
    if parsed.status >= 500:
        return f"{parsed.status}: {parsed.body[:200]!r}"
    if parsed.status >= 400 and not head and not parsed.is_json_error():
        return f"{parsed.status} is not the JSON error: {parsed.body[:120]!r}"
    return None


def _stalled_health(answer: bytes) -> bool:
    """A 503 health answer whose only error is a stalled control tick."""
    parsed = parse_answer(answer, head_only=False)
    if parsed is None or parsed.status != 503:
        return False
    try:
        control = json.loads(parsed.body)["components"]["control"]
    except (ValueError, KeyError, TypeError):
        return False
    return bool(control.get("stalled")) and not control.get("fault")


async def run_category(category: str, make: Generator, port: int, seconds: float,
                       findings: Findings) -> None:
    rng = random.Random(f"{SEED}:{category}")
    deadline = time.monotonic() + seconds
    slots = asyncio.Semaphore(PARALLEL)

    async def one(parts: list[bytes], pause: float) -> None:
        async with slots:
            findings.check(category, parts, await send_raw(port, parts, READ_S, pause))

    tasks: set[asyncio.Task[None]] = set()
    while time.monotonic() < deadline:
        await slots.acquire()
        slots.release()
        task = asyncio.create_task(one(*make(rng, port)))
        tasks.add(task)
        task.add_done_callback(tasks.discard)
        await asyncio.sleep(0)
    await asyncio.gather(*tasks)


async def burst(port: int, findings: Findings) -> None:
    """200 clients at once, each a tokenless drive command: every one answered 401."""
    data = request("POST", "/api/cmd_vel", port, b'{"linear": {"x": 1.0}}')
    answers = await asyncio.gather(*(send_raw(port, [data], 10.0) for _ in range(200)))
    findings.tried["burst of 200 clients"] += len(answers)
    findings.statuses["burst of 200 clients"] = Counter(
        int(a.split(b" ", 2)[1]) if a else 0 for a in answers)


@pytest.mark.timeout(150)
async def test_http_fuzz_moves_nothing_and_keeps_the_daemon_well(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    proc = daemon_subprocess(f'[security]\ntoken = "{TOKEN}"\n',
                          env={"ARBITERD_HTTP_IDLE_TIMEOUT_S": "1",
                               "ARBITERD_HTTP_BODY_TIMEOUT_S": "1"})
    assert proc.proc is not None
    port, pid = proc.http_port, proc.proc.pid
    for _ in range(50):  # warm up every route once before the baseline
        assert exchange(port, request("GET", "/api/status", port)).status == 200
    latch = request("POST", "/api/estop", port, b'{"engaged": true, "reason": "fuzz"}',
                    headers={"Authorization": f"Bearer {TOKEN}"})
    assert exchange(port, latch).status == 200
    rss_before = rss_kib(pid)
    findings = Findings()
    async with MachineCanary() as canary:
        for category, make in CATEGORIES.items():
            await run_category(category, make, port, BUDGET_S / len(CATEGORIES), findings)
        await burst(port, findings)
    rss_after = rss_kib(pid)

    print(f"\nHTTP fuzz, seed {SEED} (status 0: closed without an answer)")
    for name, statuses in findings.statuses.items():
        print(f"  {name}: {findings.tried[name]} inputs, {dict(sorted(statuses.items()))}")
    print(f"  daemon RSS before {rss_before} KiB, after {rss_after} KiB")
    assert not findings.problems, "\n".join(findings.problems)
    if findings.stalls:  # health said so truthfully; the stall itself must be the machine's
        control = exchange(port, request("GET", "/api/health", port)).json()["components"][
            "control"]
        limit = stall_limit_ms(canary.longest_gap_ms)
        assert control["longest_stall_ms"] <= limit, (findings.stalls, control, limit)
    assert all(findings.tried[name] >= 100 for name in CATEGORIES), findings.tried
    assert findings.statuses["burst of 200 clients"] == Counter({401: 200})
    assert proc.proc.poll() is None, proc.log()
    health = exchange(port, request("GET", "/api/health", port))
    assert health.status == 200 and health.json()["status"] == "ok"
    status = exchange(port, request("GET", "/api/status", port)).json()
    assert status["estop"]["engaged"] is True  # latched before, nobody released it
    assert not [row for row in proc.wheels() if row[1:] != (0.0, 0.0)], "a wheel moved"
    log = proc.log()
    assert "Traceback" not in log and len(log) < 100_000, log[-2000:]
    assert rss_after - rss_before < 40 * 1024, (rss_before, rss_after)
