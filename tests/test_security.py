# The trust boundary's pieces: Host allow-list, Origin parsing, token, strict JSON, quiet logs.
from __future__ import annotations

import asyncio
import errno
import logging
import time
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from daemon.components.http.conn import AcceptErrorFilter, LogLimiter
from daemon.security import Guesses, Security, hide_paths, host_name
from daemon.web import MAX_INT_DIGITS, MAX_JSON_DEPTH, ApiError, parse_json
from tests.support.in_process_daemon import in_process_daemon
from tests.support.rosbridge import OWNER, WITH_TOKEN, connect, upgrade_status
from tests.support.wait import eventually

OWN = ("robot", "robot.lan", "robot.local")


def security(**kw: Any) -> Security:
    return Security(kw.pop("token", ""), own_names=OWN, **kw)


@pytest.mark.parametrize("host", [
    None, "127.0.0.1", "127.0.0.1:8085", "[::1]:8085", "10.1.2.3", "localhost", "LOCALHOST:80",
    "localhost.", "robot", "robot.local:8085", "Robot.LAN", "192.168.1.20:1",
])
def test_hosts_this_machine_answers_to(host: str | None) -> None:
    assert security().host_ok(host)


@pytest.mark.parametrize("host", [
    "evil.example", "evil.example:8085", "robot.evil.example", "127.0.0.1.evil.example",
    "localhost.evil.example", "", ":8085", "user@127.0.0.1", "127.0.0.1:port",
    "127.0.0.1/path", "[::1", "robot.local.", "a b", "127.0.0.1:99999",
])
def test_hosts_refused(host: str) -> None:
    sec = security()
    if host == "robot.local.":  # a trailing dot is the same name
        assert sec.host_ok(host)
        return
    assert not sec.host_ok(host), host


def test_allowed_hosts_extend_the_list() -> None:
    sec = security(allowed_hosts=["Robot.Example."])
    assert sec.host_ok("robot.example:8085") and not sec.host_ok("evil.example")


@given(st.text(max_size=40))
def test_host_name_never_raises(text: str) -> None:
    name = host_name(text)
    assert name is None or name == name.lower()


@pytest.mark.parametrize(("origin", "host", "ok"), [
    (None, "evil.example", True),  # not a browser
    ("", "127.0.0.1", True),
    ("http://127.0.0.1:8085", "127.0.0.1:8085", True),
    ("http://localhost:3000", "192.168.1.20:8085", True),
    ("http://robot.local", "robot.local:8085", True),
    ("http://evil.example", "evil.example", False),  # rebinding: the Host itself is foreign
    ("http://evil.example", "127.0.0.1:8085", False),  # CSRF from another site
    ("http://127.0.0.1@evil.example", "127.0.0.1:8085", False),  # userinfo trick
    ("http://evil.example#@127.0.0.1", "127.0.0.1:8085", False),
    ("null", "127.0.0.1:8085", False),
    ("file://", "127.0.0.1", False),
    ("javascript:alert(1)", "127.0.0.1", False),
    ("http://192.168.1.20", "192.168.1.21", False),
])
def test_origins(origin: str | None, host: str, ok: bool) -> None:
    assert security().origin_ok(origin, host) is ok


def test_allowed_origins_are_exact() -> None:
    sec = security(allowed_origins=["https://console.example/"])
    assert sec.origin_ok("https://console.example", "127.0.0.1")
    assert not sec.origin_ok("https://console.example.evil", "127.0.0.1")


@pytest.mark.parametrize(("headers", "query", "ok"), [
    ({"Authorization": "Bearer T0k"}, {}, True),
    ({"Authorization": "bearer   T0k "}, {}, True),
    ({}, {"token": "T0k"}, True),
    ({"Authorization": "Bearer t0k"}, {}, False),
    ({"Authorization": "Basic T0k"}, {}, False),
    ({"Authorization": "Bearer nope"}, {"token": "T0k"}, False),  # the header wins
    ({}, {"token": "T0k\u00e9"}, False),
    ({}, {}, False),
])
def test_token(headers: dict[str, str], query: dict[str, str], ok: bool) -> None:
    assert security(token="T0k").token_ok(headers, query) is ok
    assert security().token_ok(headers, query)  # no token configured: everyone


# -- strict JSON ---------------------------------------------------------------------------

@pytest.mark.parametrize(("raw", "detail"), [
    (b"[" * (MAX_JSON_DEPTH + 1) + b"]" * (MAX_JSON_DEPTH + 1), "nested more than 32"),
    (b"[" * 200000, "nested more than 32"),
    (b"1" * (MAX_INT_DIGITS + 1), f"{MAX_INT_DIGITS + 1} digits"),
    (b'{"a": NaN}', "NaN is not a valid JSON number"),
    (b'"\xe2\x82"', "byte 0xe2 at offset 1"),
    (b"\xef\xbb\xbf{}", "BOM"),
])
def test_parse_json_refuses(raw: bytes, detail: str) -> None:
    with pytest.raises(ApiError) as err:
        parse_json(raw)
    assert err.value.status == 400
    assert detail in f"{err.value.message} {err.value.detail}"


def test_parse_json_accepts_the_limits() -> None:
    deep = b"[" * MAX_JSON_DEPTH + b"]" * MAX_JSON_DEPTH
    assert parse_json(deep) is not None
    assert parse_json(b"-" + b"9" * MAX_INT_DIGITS) == -int("9" * MAX_INT_DIGITS)
    assert parse_json('{"n": "é€😀"}'.encode()) == {"n": "é€😀"}


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=300) | st.text(max_size=100).map(str.encode))
def test_parse_json_only_ever_returns_or_raises_400(raw: bytes) -> None:
    try:
        parse_json(raw)
    except ApiError as exc:
        assert exc.status == 400 and exc.message and exc.detail


# -- quiet logs ----------------------------------------------------------------------------

def test_log_limiter_keeps_a_burst_then_counts(caplog: pytest.LogCaptureFixture) -> None:
    now = [0.0]
    limiter = LogLimiter(logging.getLogger("t"), "bad-request", burst=2, window_s=10.0,
                         clock=lambda: now[0])
    with caplog.at_level(logging.INFO, "t"):
        for i in range(50):
            limiter(logging.WARNING, "bad %d", i)
        assert [r.getMessage() for r in caplog.records] == ["bad 0", "bad 1"]
        now[0] = 10.0
        limiter(logging.WARNING, "bad %d", 99)
    assert [r.getMessage() for r in caplog.records][2:] == [
        "48 more bad-request lines not logged in the last 10 s", "bad 99"]


async def test_accept_errors_become_one_line(caplog: pytest.LogCaptureFixture) -> None:
    loop = asyncio.get_running_loop()
    seen: list[dict[str, Any]] = []
    loop.set_exception_handler(lambda _loop, context: seen.append(context))
    quiet = AcceptErrorFilter(loop)
    quiet.install()
    try:
        with caplog.at_level(logging.INFO, "arbiterd.http"):
            for _ in range(20):
                loop.call_exception_handler({
                    "message": "socket.accept() out of system resource",
                    "exception": OSError(errno.EMFILE, "Too many open files")})
            loop.call_exception_handler({"message": "something else"})
    finally:
        quiet.uninstall()
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "too many open files (EMFILE)" in lines[0]
    assert "LimitNOFILE" in lines[0] and not any(r.exc_info for r in caplog.records)
    assert quiet.count == 20
    assert seen == [{"message": "something else"}]  # everything else reaches the old handler
    assert loop.get_exception_handler() is not quiet


# -- what a read-only client is shown ------------------------------------------------------------

def test_hide_paths_hides_file_system_paths_only() -> None:
    hidden = hide_paths({"port": "/dev/ttyUSB0", "n": 3, "topics": ["/odom", "/scan"],
                         "error": "cannot open /var/lib/arbiterd/recordings: denied",
                         "url": "see http://robot.local:8085/api/health"})
    assert hidden == {"port": "<path>", "n": 3, "topics": ["/odom", "/scan"],
                      "error": "cannot open <path>: denied",
                      "url": "see http://robot.local:8085/api/health"}


async def test_a_read_only_client_is_not_shown_paths(tmp_path: Path) -> None:
    """/api/health showed the lidar's and the driver's device nodes and /api/recordings the
    recordings directory to any client; /rosout the paths in log lines and source files."""
    async with in_process_daemon(tmp_path, WITH_TOKEN) as robot, aiohttp.ClientSession() as http:
        async def text(path: str, **headers: str) -> str:
            async with http.get(robot.http_url + path, headers=headers) as answer:
                assert answer.status == 200, await answer.text()
                return await answer.text()

        for path in ("/api/health", "/api/recordings", "/api/status"):
            answer = await text(path)
            assert not any(p in answer for p in ("/tmp/", "/dev/", f"{Path.home()}/")), answer
        assert "<path>" in await text("/api/health")
        assert '"directory": "<path>"' in await text("/api/recordings")
        assert "/rplidar" in await text("/api/health", **OWNER)  # the token holder sees them
        async with connect(robot.ws_url) as reader:
            await reader.send(op="subscribe", topic="/rosout")
            await reader.call("/rosapi/get_time")
            logging.getLogger("arbiterd").warning("lost /dev/ttyUSB7")
            line = await reader.expect(lambda m: m.get("op") == "publish"
                                       and "lost" in m["msg"]["msg"])
        assert line["msg"]["msg"] == "lost <path>" and line["msg"]["file"] == "<path>"


# -- guessing the token ----------------------------------------------------------------------

def test_wrong_tokens_are_limited_per_peer() -> None:
    now = [0.0]
    sec = security(token="right-token-1")
    sec.guesses = Guesses(rate=1.0, burst=10, clock=lambda: now[0])
    wrong, right = {"Authorization": "Bearer nope"}, {"Authorization": "Bearer right-token-1"}
    assert [sec.token_ok(wrong, {}, "10.0.0.9") for _ in range(10)] == [False] * 10
    assert sec.guessing(wrong, {}, "10.0.0.9") and not sec.guessing(right, {}, "10.0.0.9")
    assert sec.check_token(wrong, {}, "10.0.0.9") == "guessing"  # refused while over budget
    assert sec.token_ok(right, {}, "10.0.0.9")  # the right token is never locked out
    assert sec.token_ok(right, {}, "10.0.0.10")  # another address is not held back
    assert not sec.guessing({}, {}, "10.0.0.9")  # no token offered: no guess
    assert sec.check_token({}, {}, "10.0.0.9") == "missing"
    now[0] += 1.0
    assert sec.check_token(wrong, {}, "10.0.0.9") == "wrong"  # a second later one more try


async def test_the_right_token_passes_during_a_guessing_flood(tmp_path: Path) -> None:
    """Before: with 556 wrong tokens a second from one address, the right token from the
    same address got 429 six times in six, and for 1.4 s after."""
    locked = WITH_TOKEN + "read_requires_token = true\n"
    async with in_process_daemon(tmp_path, locked) as robot, aiohttp.ClientSession() as http:
        url = robot.http_url + "/api/status"
        wrong = {"Authorization": "Bearer not-the-token"}
        flood: list[int] = []
        done = asyncio.Event()

        async def guess() -> None:
            while not done.is_set():
                async with http.get(url, headers=wrong) as answer:
                    flood.append(answer.status)

        guessers = [asyncio.create_task(guess()) for _ in range(8)]
        try:
            await eventually(lambda: flood.count(429) >= 50, "the flood to be over budget")
            started, before, owner = time.monotonic(), len(flood), []
            for _ in range(20):
                async with http.get(url, headers=OWNER) as answer:
                    owner.append(answer.status)
            rate = (len(flood) - before) / max(time.monotonic() - started, 1e-3)
        finally:
            done.set()
            await asyncio.gather(*guessers)
        print(f"right token during a flood of {len(flood)} wrong ones ({rate:.0f}/s meanwhile, "
              f"{flood.count(429)} answered 429): {owner.count(200)} of {len(owner)} accepted")
        assert owner == [200] * 20 and set(flood) == {401, 429}


async def test_token_guessing_is_refused_with_429_on_both_ports(tmp_path: Path) -> None:
    """Wrong tokens were unlimited (8 555 guesses a second over HTTP)."""
    async with in_process_daemon(tmp_path, WITH_TOKEN) as robot, aiohttp.ClientSession() as http:
        statuses = []
        for n in range(30):
            async with http.post(robot.http_url + "/api/cmd_vel", json={"linear": {"x": 0.2}},
                                 headers={"Authorization": f"Bearer guess-{n:08d}"}) as answer:
                statuses.append(answer.status)
        assert statuses[:10] == [401] * 10 and set(statuses[10:]) == {429}, statuses
        assert await upgrade_status(robot.ws_url + "?token=guess") == 429
        assert await upgrade_status(robot.ws_url) == 101  # without a token: read-only, as ever
        assert not robot.moving()
