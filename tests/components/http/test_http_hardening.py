# HTTP as a hostile client or a flaky network sees it: Host/Origin, bodies, parser errors, sockets.
from __future__ import annotations

import math
import socket
import zlib
from collections.abc import Iterator

import pytest

from daemon.latency import SourceCounts
from tests.support.daemon_subprocess import DaemonSubprocess, StartDaemonSubprocess
from tests.support.http_raw import (
    Answer,
    child_nofile,
    closed_by_peer,
    connect,
    drip_is_refused,
    exchange,
    quiet_for,
    read_answer,
    request,
)
from tests.support.wait import wait_for

GO = b'{"linear": {"x": 0.2}}'


@pytest.fixture(scope="module")
def robot_proc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonSubprocess]:
    """``arbiterd run`` (mock driver logging its wheels), default security, short timeouts."""
    tmp = tmp_path_factory.mktemp("hardening")
    with DaemonSubprocess(tmp, env={"ARBITERD_HTTP_BODY_TIMEOUT_S": "2"}) as proc:
        yield proc


def moved(proc: DaemonSubprocess, since: int = 0) -> bool:
    return any((left, right) != (0.0, 0.0) for _, left, right in proc.wheels()[since:])


def at_rest(proc: DaemonSubprocess) -> bool:
    rows = proc.wheels()
    return not rows or rows[-1][1:] == (0.0, 0.0)


def at_rest_since(proc: DaemonSubprocess) -> int:
    """Wait for the wheels to stand still (the deadman stops earlier tests' motion); the
    wheel-log index to check "nothing moved" from."""
    wait_for(lambda: at_rest(proc), "the robot at rest")
    return len(proc.wheels())


def post(proc: DaemonSubprocess, body: bytes = GO, **kw: object) -> Answer:
    return exchange(proc.http_port, request("POST", "/api/cmd_vel", proc.http_port, body,
                                            **kw))  # type: ignore[arg-type]


# -- who may reach it, who may drive -------------------------------------------------------

def test_dns_rebinding_gets_403_in_the_default_config(robot_proc: DaemonSubprocess) -> None:
    before = at_rest_since(robot_proc)
    answer = post(robot_proc, host="evil.example",
                  headers={"Origin": "http://evil.example"})
    assert answer.status == 403 and answer.is_json_error()
    assert "evil.example" in answer.json()["error"]
    assert "[security] allowed_hosts" in answer.json()["detail"]
    for path in ("/api/health", "/api/status", "/nothing"):
        got = exchange(robot_proc.http_port, request("GET", path, 0, host="evil.example:8085"))
        assert got.status == 403, path
    assert not moved(robot_proc, before)


def test_a_listed_host_name_is_answered(daemon_subprocess: StartDaemonSubprocess) -> None:
    proc = daemon_subprocess('[security]\nallowed_hosts = ["Robot.Example"]\n')
    for host in ("robot.example", "ROBOT.example.:8085", "127.0.0.1", "localhost:1",
                 "[::1]:80", socket.gethostname()):
        answer = exchange(proc.http_port, request("GET", "/api/health", 0, host=host))
        assert answer.status == 200, host
    assert exchange(proc.http_port, request("GET", "/api/health", 0,
                                            host="robot.example.evil")).status == 403


@pytest.mark.parametrize("origin", [
    "http://evil.example", "null", "http://127.0.0.1@evil.example",
    "https://evil.example:443", "file://", "ftp://127.0.0.1",
])
def test_a_foreign_origin_cannot_drive(robot_proc: DaemonSubprocess, origin: str) -> None:
    before = at_rest_since(robot_proc)
    answer = post(robot_proc, headers={"Origin": origin})
    assert answer.status == 403 and answer.is_json_error(), answer
    assert "[security] allowed_origins" in answer.json()["detail"]
    assert not moved(robot_proc, before)


def test_the_daemons_own_origin_drives_and_reads_carry_no_cors(
        robot_proc: DaemonSubprocess) -> None:
    own = f"http://127.0.0.1:{robot_proc.http_port}"
    before = at_rest_since(robot_proc)
    assert post(robot_proc, headers={"Origin": own}).status == 200
    wait_for(lambda: moved(robot_proc, before), "motion")
    read = exchange(robot_proc.http_port, request("GET", "/api/status", 0,
                                                  headers={"Origin": "http://evil.example"}))
    assert read.status == 200
    preflight = exchange(robot_proc.http_port, request(
        "OPTIONS", "/api/cmd_vel", 0, headers={"Origin": "http://evil.example",
                                               "Access-Control-Request-Method": "POST"}))
    assert preflight.status == 405 and preflight.headers["allow"] == "POST"
    for answer in (read, preflight):
        assert not [h for h in answer.headers if h.startswith("access-control-")]
    wait_for(lambda: at_rest(robot_proc), "the deadman stop")


def test_the_token_is_needed_even_from_the_own_origin(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    proc = daemon_subprocess('[security]\ntoken = "t0k-t0k-t0k-t0k"\n')
    own = {"Origin": f"http://127.0.0.1:{proc.http_port}"}
    answer = post(proc, headers=own)
    assert answer.status == 401 and answer.headers["www-authenticate"].startswith("Bearer")
    assert post(proc, headers={**own, "Authorization": "Bearer t0k-t0k-t0k-t0k"}).status == 200
    assert post(proc, headers={"Origin": "http://evil.example",
                               "Authorization": "Bearer t0k-t0k-t0k-t0k"}).status == 403


# -- request bodies ------------------------------------------------------------------------

def test_a_body_in_two_tcp_segments_is_read_whole(robot_proc: DaemonSubprocess) -> None:
    before = at_rest_since(robot_proc)
    data = request("POST", "/api/cmd_vel", robot_proc.http_port, GO)
    split = len(data) - len(GO) + 7
    with connect(robot_proc.http_port) as sock:
        sock.sendall(data[:split])
        assert quiet_for(sock, 0.3), "answered before the rest of the body arrived"
        sock.sendall(data[split:])
        answer = read_answer(sock)
    assert answer.status == 200 and answer.json()["accepted"], answer
    wait_for(lambda: moved(robot_proc, before), "motion")


def test_a_chunked_body_in_pieces_is_read_whole(robot_proc: DaemonSubprocess) -> None:
    head = request("POST", "/api/cmd_vel", robot_proc.http_port, b"",
                   headers={"Content-Type": "application/json",
                            "Transfer-Encoding": "chunked"})
    with connect(robot_proc.http_port) as sock:
        sock.sendall(head)
        for piece in (GO[:5], GO[5:12], GO[12:]):
            sock.sendall(b"%x\r\n%s\r\n" % (len(piece), piece))
            assert quiet_for(sock, 0.05)
        sock.sendall(b"0\r\n\r\n")
        assert read_answer(sock).status == 200


def test_a_body_that_never_completes_gets_408(robot_proc: DaemonSubprocess) -> None:
    data = request("POST", "/api/cmd_vel", robot_proc.http_port, GO)
    with connect(robot_proc.http_port) as sock:
        sock.sendall(data[:-4])
        answer = read_answer(sock, within_s=10)
    assert answer.status == 408 and answer.is_json_error()
    assert "body_timeout_s" in answer.json()["detail"]


BAD_BODIES = {
    "nested 1000 deep (arrays)": (b"[" * 1000 + b"]" * 1000, "nested more than 32 deep"),
    "nested 1000 deep (objects)": (b'{"a":' * 1000 + b"1" + b"}" * 1000, "nested more than"),
    "nested 100000 deep": (b"[" * 60000, "nested more than"),
    "400-digit integer": (b'{"linear": {"x": ' + b"9" * 400 + b"}}", "400 digits"),
    "400-digit negative id": (b'{"id": -' + b"1" * 400 + b"}", "400 digits"),
    "invalid UTF-8": (b'{"linear": {"x": 0.1}, "id": "\xff"}', "0xff at offset 30"),
    "overlong UTF-8": (b'{"id": "\xc0\xaf"}', "offset 8"),
    "UTF-16 JSON": ('{"linear": {"x": 0.1}}'.encode("utf-16"), "not valid UTF-8"),
    "lone surrogate bytes": (b'{"id": "\xed\xa0\x80"}', "offset 8"),
}


@pytest.mark.parametrize("case", list(BAD_BODIES))
def test_bad_bodies_are_400_json_errors(robot_proc: DaemonSubprocess, case: str) -> None:
    body, detail = BAD_BODIES[case]
    before = at_rest_since(robot_proc)
    answer = post(robot_proc, body)
    assert answer.status == 400 and answer.is_json_error(), answer
    assert detail in answer.json()["error"] + " " + answer.json()["detail"]
    assert not moved(robot_proc, before)


def test_a_corrupt_deflate_body_is_400_and_a_good_one_works(robot_proc: DaemonSubprocess) -> None:
    deflate = {"Content-Encoding": "deflate"}
    answer = post(robot_proc, b"\x78\x9cnot deflate at all", headers=deflate)
    assert answer.status == 400 and answer.is_json_error()
    assert answer.json()["error"] == "body cannot be read"
    truncated = zlib.compress(b'{"linear": {"x": 0.0}, "id": "' + b"z" * 500 + b'"}')[:40]
    assert post(robot_proc, truncated, headers=deflate).status == 400
    assert post(robot_proc, zlib.compress(b'{"linear": {"x": 0.0}}'),
                headers=deflate).status == 200
    bomb = zlib.compress(b" " * 20_000_000, 9)  # 20 MB of spaces in ~20 KB
    answer = post(robot_proc, bomb, headers=deflate)
    assert answer.status == 413 and answer.is_json_error()
    assert exchange(robot_proc.http_port, request("GET", "/api/health", 0)).status == 200


H = "Host: 127.0.0.1\r\n"
MALFORMED = {
    "bad method": "GARBAGE\r\n\r\n",
    "bad version": f"GET /api/health HTTP/9.9\r\n{H}\r\n",
    "header without colon": "GET /api/health HTTP/1.1\r\nHost 127.0.0.1\r\n\r\n",
    "space in a header name": f"GET /api/health HTTP/1.1\r\n{H}Bad Header: x\r\n\r\n",
    "oversized header": f"GET /api/health HTTP/1.1\r\n{H}X-Big: {'a' * 20000}\r\n\r\n",
    "oversized request line": f"GET /{'a' * 20000} HTTP/1.1\r\n{H}\r\n",
    "too many headers": f"GET /api/health HTTP/1.1\r\n{H}"
                        + "".join(f"X-{i}: 1\r\n" for i in range(300)) + "\r\n",
    "content-length not a number": f"POST /api/cmd_vel HTTP/1.1\r\n{H}Content-Length: x\r\n\r\n",
    "negative content-length": f"POST /api/cmd_vel HTTP/1.1\r\n{H}Content-Length: -1\r\n\r\n",
    "two content-lengths": f"POST /api/cmd_vel HTTP/1.1\r\n{H}Content-Length: 2\r\n"
                           "Content-Length: 3\r\n\r\n{}",
    "bad chunk size": f"POST /api/cmd_vel HTTP/1.1\r\n{H}Transfer-Encoding: chunked\r\n\r\n"
                      "zz\r\n{}\r\n0\r\n\r\n",
    "huge chunk size": f"POST /api/cmd_vel HTTP/1.1\r\n{H}Transfer-Encoding: chunked\r\n\r\n"
                       "ffffffffffffffffffff\r\n{}\r\n0\r\n\r\n",
    "chunked and content-length": f"POST /api/cmd_vel HTTP/1.1\r\n{H}Transfer-Encoding: "
                                  "chunked\r\nContent-Length: 2\r\n\r\n2\r\n{}\r\n0\r\n\r\n",
    "unknown transfer-encoding": f"POST /api/cmd_vel HTTP/1.1\r\n{H}Transfer-Encoding: "
                                 "gzip\r\n\r\n",
    "NUL in a header": f"GET /api/health HTTP/1.1\r\n{H}X: a\x00b\r\n\r\n",
    "bare CR in a header": f"GET /api/health HTTP/1.1\r\n{H}X: a\rb\r\n\r\n",
    "bare LF line ends": "GET /api/health HTTP/1.1\nHost: 127.0.0.1\n\n",
    "obs-fold header": f"GET /api/health HTTP/1.1\r\n{H}X: a\r\n  b\r\n\r\n",
    "space in the path": f"GET /a b HTTP/1.1\r\n{H}\r\n",
    "two Host headers": f"GET /api/health HTTP/1.1\r\n{H}Host: evil.example\r\n\r\n",
    "HTTP/2 preface": "PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n",
    "TLS ClientHello": "\x16\x03\x01\x00\xa5\x01\x00\x00\xa1\x03\x03" + "\x07" * 40,
    "HTTP/0.9 request line": "GET /api/health\r\n\r\n",  # was answered 200
}


@pytest.mark.parametrize("case", list(MALFORMED))
def test_parser_errors_are_json_400(robot_proc: DaemonSubprocess, case: str) -> None:
    answer = exchange(robot_proc.http_port, MALFORMED[case].encode("latin-1"))
    assert answer.status == 400 and answer.is_json_error(), answer
    assert answer.json()["error"] == "malformed HTTP request" and answer.json()["detail"]


@pytest.mark.parametrize("path", ["/api/health", "/api/cmd_vel", "/nothing"])
def test_an_unknown_expect_is_a_json_417(robot_proc: DaemonSubprocess, path: str) -> None:
    answer = exchange(robot_proc.http_port, request("GET", path, 0,
                                                    headers={"Expect": "teapot"}))
    assert answer.status == 417 and answer.is_json_error(), answer
    assert "teapot" in answer.json()["detail"]


def test_bad_requests_are_logged_as_rate_limited_lines_without_traceback(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    proc = daemon_subprocess()
    for case in list(MALFORMED) * 2:
        exchange(proc.http_port, MALFORMED[case].encode("latin-1"))
    for body, _ in BAD_BODIES.values():
        post(proc, body)
    post(proc, b"\x78\x9cnot deflate", headers={"Content-Encoding": "deflate"})
    assert exchange(proc.http_port, request("GET", "/api/health", 0)).status == 200
    log = proc.log()
    assert "Traceback" not in log
    bad = [line for line in log.splitlines() if "bad HTTP request" in line]
    assert 1 <= len(bad) <= 5, bad


def test_a_body_cut_off_by_the_client_is_one_line_without_traceback(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    proc = daemon_subprocess()
    with connect(proc.http_port) as sock:  # 22 of the 100 bytes it announces, then gone
        sock.sendall(request("POST", "/api/cmd_vel", proc.http_port, b'{"linear": {"x": 0.1}}',
                             headers={"Content-Length": "100"}))
    wait_for(lambda: "cut off" in proc.log(), "the cut-off body's log line")
    assert exchange(proc.http_port, request("GET", "/api/health", 0)).status == 200
    log = proc.log()
    assert "Traceback" not in log and "ConnectionResetError" not in log, log[-2000:]


@pytest.mark.parametrize("path", ["/api/health", "/api/nothing", "/api/cmd_vel"])
def test_api_answers_say_nosniff_and_no_store(robot_proc: DaemonSubprocess, path: str) -> None:
    answer = exchange(robot_proc.http_port, request("GET", path, 0))
    assert answer.headers.get("x-content-type-options") == "nosniff", answer.headers
    assert answer.headers.get("cache-control") == "no-store", answer.headers
    assert answer.status in (200, 404, 405)


def test_405_names_the_allowed_methods_and_get_answers_head(
        robot_proc: DaemonSubprocess) -> None:
    answer = exchange(robot_proc.http_port, request("POST", "/api/health", 0))
    assert answer.status == 405 and answer.is_json_error()
    assert answer.headers["allow"] == "GET,HEAD"
    assert exchange(robot_proc.http_port, request("DELETE", "/api/cmd_vel", 0)).headers[
        "allow"] == "POST"
    with connect(robot_proc.http_port) as sock:
        sock.sendall(request("HEAD", "/api/health", 0))
        head = read_answer(sock, head_only=True)
        assert head.status == 200 and int(head.headers["content-length"]) > 0
        assert head.body == b"" and closed_by_peer(sock, 5)  # the head only, then close


# -- connections ---------------------------------------------------------------------------

def test_idle_and_slow_header_connections_are_closed(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    proc = daemon_subprocess(env={"ARBITERD_HTTP_IDLE_TIMEOUT_S": "0.5"})
    with connect(proc.http_port) as idle:
        assert closed_by_peer(idle, 10)
    with connect(proc.http_port) as slow:
        slow.sendall(b"GET /api/health HTTP/1.1\r\n")
        closed = wait_for(lambda: drip_is_refused(slow), "the slow client to be cut off")
        assert closed
    answer = exchange(proc.http_port, b"GET /api/health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    assert answer.status == 200  # keep-alive answered; the next idle period closes it too




def test_1100_idle_connections_do_not_take_the_descriptors(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    with child_nofile(1024):  # the usual soft limit without the unit's LimitNOFILE
        proc = daemon_subprocess()
    idle = []
    try:
        for _ in range(1100):
            idle.append(connect(proc.http_port))
        answer = exchange(proc.http_port, request("GET", "/api/health", 0))
        assert answer.status == 200, answer
        http = answer.json()["components"]["http"]
        assert http["connections"] <= 256 and http["connections_refused"] >= 1100 - 256
    finally:
        for sock in idle:
            sock.close()
    log = proc.log()
    assert "Traceback" not in log and "cannot accept" not in log
    assert proc.proc is not None and proc.proc.poll() is None


def test_accept_errors_are_one_line_and_the_daemon_recovers(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    with child_nofile(96):
        proc = daemon_subprocess(env={"ARBITERD_HTTP_MAX_CONNECTIONS": "4096"})
    held = []
    try:
        for _ in range(200):
            try:
                sock = socket.create_connection(("127.0.0.1", proc.http_port), timeout=0.2)
            except OSError:
                continue
            held.append(sock)
        wait_for(lambda: "cannot accept connections" in proc.log(), "the accept error line")
        # asyncio retries accept() every second; let it fail a few more times
        assert not health_answered(proc, within_s=2.5)
    finally:
        for sock in held:
            sock.close()
    assert wait_for(lambda: health_answered(proc, 1.0), "health after the flood")
    log = proc.log()
    assert log.count("cannot accept connections: too many open files (EMFILE)") == 1
    assert "Traceback" not in log and "socket.accept() out of system resource" not in log


def health_answered(proc: DaemonSubprocess, within_s: float) -> bool:
    """One GET /api/health answered 200 within ``within_s``."""
    try:
        return exchange(proc.http_port, request("GET", "/api/health", 0), within_s).status == 200
    except (OSError, AssertionError):
        return False


# -- bounded memory ------------------------------------------------------------------------

def test_per_source_counts_are_capped_and_expire() -> None:
    now = [0.0]
    counts = SourceCounts(max_sources=3, idle_s=10.0, clock=lambda: now[0])
    for i in range(5):
        counts.add(f"ws:{i}")
        now[0] += 1.0
    counts.add("ws:2")
    assert counts.snapshot() == {"ws:3": 1, "ws:4": 1, "ws:2": 2}
    assert counts.dropped == 2
    now[0] += 9.5  # ws:3 silent for 11.5 s, ws:4 for 10.5 s, ws:2 for 9.5 s
    assert counts.snapshot() == {"ws:2": 2} and counts.dropped == 4


def test_latency_reports_the_per_source_limits(robot_proc: DaemonSubprocess) -> None:
    assert post(robot_proc, b'{"linear": {"x": 0.0}}').status == 200
    status, latency = robot_proc.get("/api/latency")
    assert status == 200 and latency["per_source"]["http"] >= 1
    assert latency["per_source_limits"] == {"max_sources": 64, "idle_expiry_s": 600.0,
                                            "dropped": 0}


def test_a_refused_command_is_answered_409_and_not_logged_as_a_bad_request(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    proc = daemon_subprocess()
    assert proc.post("/api/estop", {"engaged": True, "reason": "test"})[0] == 200
    for _ in range(3):
        status, body = proc.post("/api/cmd_vel", {"linear": {"x": 0.1}})
        assert status == 409 and "e-stop" in body["error"], body
    # a bad request after them is logged: once its line is there, theirs would be too
    assert proc.post("/api/cmd_vel", {"linear": {"x": math.inf}})[0] == 400
    log = wait_for(lambda: "bad HTTP request" in proc.log() and proc.log(), "the 400's line")
    assert [line for line in log.splitlines() if "409" in line] == []
