# Socket floods on both ports: idle connections, slow headers, stalled readers. Nobody without
# the token locks out health, the e-stop or the token holder's WebSocket.
from __future__ import annotations

import base64
import os
import socket
from pathlib import Path

from daemon.bench.rosbridge_attacks import run_attack
from tests.support.daemon_subprocess import DaemonSubprocess, StartDaemonSubprocess
from tests.support.http_raw import (
    LOCAL,
    Answer,
    child_nofile,
    closed_by_peer,
    connect,
    drip_is_refused,
    exchange,
    request,
    stalled_download,
)
from tests.support.rosbridge import TOKEN, WITH_TOKEN
from tests.support.wait import wait_for

BEARER = {"Authorization": f"Bearer {TOKEN}"}


def upgrade_request(port: int, token: str | None = None) -> bytes:
    key = base64.b64encode(os.urandom(16)).decode()
    query = f"?token={token}" if token else ""
    return (f"GET /{query} HTTP/1.1\r\nHost: {LOCAL}:{port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
            f"Sec-WebSocket-Version: 13\r\n\r\n").encode()


def upgrade_status(port: int, token: str | None = None, within_s: float = 5.0) -> int:
    """The status line's code of a WebSocket upgrade (101: a WebSocket), or 0 if the
    connection was refused, closed or silent."""
    try:
        with connect(port) as sock:
            sock.settimeout(within_s)
            sock.sendall(upgrade_request(port, token))
            head = sock.recv(4096)
    except OSError:
        return 0
    return int(head.split()[1]) if head.startswith(b"HTTP/1.1 ") else 0


def health(proc: DaemonSubprocess, within_s: float = 5.0) -> Answer | None:
    try:
        return exchange(proc.http_port, request("GET", "/api/health", 0), within_s)
    except (OSError, AssertionError):
        return None


def estop(proc: DaemonSubprocess, engaged: bool, within_s: float = 5.0) -> int:
    body = b'{"engaged": true}' if engaged else b'{"engaged": false}'
    try:
        return exchange(proc.http_port, request("POST", "/api/estop", 0, body, headers=BEARER),
                        within_s).status
    except (OSError, AssertionError):
        return 0


def open_idle(port: int, count: int) -> list[socket.socket]:
    """``count`` connections that send nothing (those the kernel refuses are not counted)."""
    sockets = []
    for _ in range(count):
        try:
            sockets.append(socket.create_connection((LOCAL, port), timeout=0.5))
        except OSError:
            continue
    return sockets


# -- the rosbridge port ------------------------------------------------------------------------

def test_idle_sockets_on_the_rosbridge_port_lock_nobody_out(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    """1 100 idle TCP connections to :9090 with 1 024 descriptors: before, they took every
    descriptor (no cap, no handshake timeout) and HTTP health, the HTTP e-stop and the token
    holder's WebSocket all failed while they were held."""
    with child_nofile(1024):  # the usual soft limit without the unit's LimitNOFILE
        proc = daemon_subprocess(WITH_TOKEN)
    idle = open_idle(proc.ws_port, 1100)
    try:
        answer = health(proc)
        assert answer is not None and answer.status == 200, answer
        assert estop(proc, True) == 200 and estop(proc, False) == 200
        assert upgrade_status(proc.ws_port, TOKEN) == 101
        rosbridge = health(proc).json()["components"]["rosbridge"]  # type: ignore[union-attr]
        assert rosbridge["open_connections"] <= 256, rosbridge
        assert rosbridge["connections_closed_at_cap"] >= len(idle) - 256, rosbridge
    finally:
        for sock in idle:
            sock.close()
    log = proc.log()
    assert "Traceback" not in log and "cannot accept" not in log, log[-3000:]


def test_slow_upgrade_headers_on_the_rosbridge_port_are_cut_off(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    """A connection that never completes its upgrade request (slowloris) is closed after
    ``[rosbridge] handshake_timeout_s``; before, 300 of them were still open after 60 s."""
    proc = daemon_subprocess(env={"ARBITERD_ROSBRIDGE_HANDSHAKE_TIMEOUT_S": "0.5"})
    with connect(proc.ws_port) as idle:
        assert closed_by_peer(idle, 10)
    with connect(proc.ws_port) as slow:
        slow.sendall(upgrade_request(proc.ws_port)[:30])
        assert wait_for(lambda: drip_is_refused(slow), "the slow client to be cut off")
    assert upgrade_status(proc.ws_port) == 101  # a prompt client still gets in




# -- the HTTP port -----------------------------------------------------------------------------

RECORDING = "arbiterd-big.mcap"




def test_stalled_downloads_leave_health_and_the_estop_a_way_in(
        daemon_subprocess: StartDaemonSubprocess, tmp_path: Path) -> None:
    """More stalled downloads than HTTP connection slots (20 with the cap at 16; the finding:
    260 with 256): before, health and the e-stop got 0 of 5 and every refused connection
    logged an AssertionError traceback; and the downloads were held with no time limit."""
    recordings = tmp_path / "recordings"
    recordings.mkdir()
    with (recordings / RECORDING).open("wb") as sparse:
        sparse.truncate(256 * 1024 * 1024)
    proc = daemon_subprocess(WITH_TOKEN + f'[recorder]\ndirectory = "{recordings}"\n',
                             env={"ARBITERD_HTTP_MAX_CONNECTIONS": "16",
                                  "ARBITERD_HTTP_SEND_TIMEOUT_S": "3"})
    downloads = []
    try:
        for _ in range(20):
            try:
                downloads.append(stalled_download(proc.http_port, RECORDING))
            except (OSError, AssertionError):
                continue  # over the cap: refused; the point is what health sees now
        assert len(downloads) >= 16
        answers = [health(proc, 2.0) for _ in range(5)]
        assert all(a is not None and a.status == 200 for a in answers), answers
        assert [estop(proc, engaged, 2.0) for engaged in (True, False) * 2] == [200] * 4
        # a stalled reader is closed once its answer made no progress for send_timeout_s
        wait_for(lambda: (h := health(proc, 2.0)) is not None
                 and h.json()["components"]["http"]["connections"] <= 4,
                 "the stalled downloads to be closed")
    finally:
        for sock in downloads:
            sock.close()
    log = proc.log()
    assert "Traceback" not in log and "AssertionError" not in log, log[-3000:]
    assert "made no progress for 3 s" in log


# -- the attack tool, from its own process -----------------------------------------------------

async def test_the_attack_tool_sees_slow_headers_and_stalled_readers_cut_off(
        daemon_subprocess: StartDaemonSubprocess, tmp_path: Path) -> None:
    recordings = tmp_path / "recordings"
    recordings.mkdir()
    with (recordings / RECORDING).open("wb") as sparse:
        sparse.truncate(256 * 1024 * 1024)
    proc = daemon_subprocess(f'[recorder]\ndirectory = "{recordings}"\n',
                             env={"ARBITERD_ROSBRIDGE_HANDSHAKE_TIMEOUT_S": "1",
                                  "ARBITERD_HTTP_IDLE_TIMEOUT_S": "1",
                                  "ARBITERD_HTTP_SEND_TIMEOUT_S": "1"})
    ws, http = f"ws://{LOCAL}:{proc.ws_port}/", f"http://{LOCAL}:{proc.http_port}"
    for url, drip in ((ws, "0"), (ws, "1"), (http, "1")):
        report = await run_attack(url, "idle-sockets", "--count", "50", "--seconds", "15",
                                  "--drip", drip)
        assert report["closed_by_server"] == report["opened"] == 50, (url, drip, report)
    report = await run_attack(f"{http}/api/recordings/{RECORDING}", "stalled-readers",
                              "--count", "20", "--seconds", "15")
    assert report["answers"] == {"200": 20} and report["cut_off_by_server"] == 20, (
        report, proc.log()[-2000:])
    assert "Traceback" not in proc.log()
