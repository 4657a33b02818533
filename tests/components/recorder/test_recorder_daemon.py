# The flight recorder in `arbiterd run --sim`: SIGTERM and SIGKILL files read back by the mcap
# Python reader and by @mcap/core on Node, the HTTP control, and a broken directory that must not
# stop the robot.
from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from daemon.components.recorder.files import inspect
from daemon.components.recorder.writer import recordings
from tests.support.compare import close_to
from tests.support.daemon_subprocess import DaemonSubprocess, StartDaemonSubprocess
from tests.support.paths import REPO
from tests.support.wait import wait_for

INTEROP = REPO / "tests" / "interop"
RECORDED = {"/odom", "/tf", "/tf_static", "/scan", "/commands", "/latency_reports", "/rosout",
            "/diagnostics", "/odom_ground_truth", "/autonomy/state", "/collision_monitor/state",
            "/navigation/state", "/fetch/state", "/dock/state"}


def record_toml(directory: Path, extra: str = "") -> str:
    return f'[recorder]\nenabled = true\ndirectory = "{directory}"\n{extra}'


def drive(daemon: DaemonSubprocess, linear: float, angular: float, cmd_id: str) -> None:
    status, body = daemon.post("/api/cmd_vel", {
        "linear": {"x": linear}, "angular": {"z": angular}, "id": cmd_id,
        "t_sent": time.time() * 1000})
    assert status == 200, body


def pose(daemon: DaemonSubprocess) -> dict[str, float]:
    status, body = daemon.get("/api/status")
    assert status == 200
    return dict(body["pose"])


def drive_and_stop(daemon: DaemonSubprocess) -> dict[str, float]:
    """Drive a little, stop, and return the pose once the robot stands still."""
    start = pose(daemon)

    def moved() -> bool:
        drive(daemon, 0.3, 0.4, "go")
        return math.hypot(pose(daemon)["x"] - start["x"], pose(daemon)["y"] - start["y"]) > 0.05

    wait_for(moved, "the robot to move", interval_s=0.1)
    drive(daemon, 0.0, 0.0, "stop")
    previous: dict[str, Any] = {}

    def still() -> dict[str, float] | None:
        nonlocal previous
        now = pose(daemon)
        settled = now == previous
        previous = now
        return now if settled else None

    return wait_for(still, "the robot to stand still", interval_s=0.3)


def decoded(path: Path) -> list[tuple[str, int, Any]]:
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [(c.topic, m.log_time, msg) for _, c, m, msg in reader.iter_decoded_messages(
            log_time_order=False)]


def node_read(path: Path, *extra: str) -> dict[str, Any]:
    node = shutil.which("node")
    if node is None or not (INTEROP / "node_modules" / "@mcap" / "core").exists():
        pytest.fail("node and tests/interop/node_modules are prerequisites: run ./install.sh dev")
    result = subprocess.run([node, str(INTEROP / "mcap_read.mjs"), str(path), *extra],
                            cwd=INTEROP, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    body: dict[str, Any] = json.loads(result.stdout)
    return body


def arbiterd(*args: str) -> str:
    result = subprocess.run([sys.executable, "-m", "daemon.cli", *args], cwd=REPO,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    return result.stdout


def the_recording(directory: Path) -> Path:
    (path,) = recordings(directory)
    return path


def test_a_sigterm_recording_reads_back_in_python_and_node(
        daemon_subprocess: StartDaemonSubprocess, tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    daemon = daemon_subprocess(record_toml(rec), args=("--sim",))
    final = drive_and_stop(daemon)  # /odom went out many times since the robot stood still
    assert daemon.stop() == 0

    path = the_recording(rec)
    info = inspect(path)
    # /plan has its channel from the start and no message: no goal was sent
    assert info.complete and set(info.topics) == RECORDED | {"/plan"}
    messages = decoded(path)
    assert {t for t, _, _ in messages} == RECORDED
    times = [t for _, t, _ in messages]
    assert times == sorted(times)
    last_odom = [m for t, _, m in messages if t == "/odom"][-1].pose.pose
    assert close_to([last_odom.position.x, last_odom.position.y], [final["x"], final["y"]], 1e-9)
    assert close_to(2 * math.atan2(last_odom.orientation.z, last_odom.orientation.w),
                    final["theta"], 1e-9)
    commands = [m for t, _, m in messages if t == "/commands"]
    assert {(c.source, c.kind, c.id) for c in commands} >= {("http", "cmd_vel", "go"),
                                                         ("http", "cmd_vel", "stop")}
    assert any("stopping" in m.msg or "shutting down" in m.msg
               for t, _, m in messages if t == "/rosout")

    node = node_read(path)
    assert node["profile"] == "ros2" and node["monotonic"] is True
    assert {t: v["count"] for t, v in node["topics"].items()} == {  # Node lists what it read
        t: v.count for t, v in info.topics.items() if v.count}
    assert all(v["decoded"] == v["count"] and v["messageEncoding"] == "cdr"
               and v["schemaEncoding"] == "ros2msg" for v in node["topics"].values())
    assert close_to([node["lastOdom"]["x"], node["lastOdom"]["y"]], [final["x"], final["y"]],
                    1e-9)

    listing = arbiterd("record", "list", "--dir", str(rec))
    assert path.name in listing
    described = arbiterd("record", "info", str(path))
    assert "complete" in described and "/odom" in described and "/commands" in described


def test_after_sigkill_all_but_the_last_second_reads_back(
        daemon_subprocess: StartDaemonSubprocess, tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    daemon = daemon_subprocess(record_toml(rec), args=("--sim",))
    wait_for(lambda: recordings(rec) and inspect(the_recording(rec)).duration_s > 2.0,
             "two seconds on disk", within_s=20)
    killed_at = time.time()
    assert daemon.stop(signal.SIGKILL) == -signal.SIGKILL
    info = inspect(the_recording(rec))
    assert not info.complete
    assert info.topics["/odom"].count > 20
    assert info.end_ns is not None
    # flush_interval_s = 1: the chunk in progress is lost; allow the writer's poll and slack
    assert info.end_ns / 1e9 > killed_at - 2.0
    node = node_read(the_recording(rec), "--stream")
    assert node["topics"]["/odom"]["decoded"] == info.topics["/odom"].count
    assert "not closed" in arbiterd("record", "info", str(the_recording(rec)))


def test_an_unwritable_directory_degrades_health_and_the_robot_still_drives(
        daemon_subprocess: StartDaemonSubprocess, tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory\n")
    daemon = daemon_subprocess(record_toml(blocker / "recordings"), args=("--sim",))

    def degraded() -> Any:
        _, health = daemon.get("/api/health")
        recorder = health["components"]["recorder"]
        return health if recorder["status"] == "degraded" == health["status"] else None

    health = wait_for(degraded, "the recorder to degrade the daemon's health")
    assert str(blocker / "recordings") in health["components"]["recorder"]["error"]
    drive_and_stop(daemon)  # fails unless the robot moves
    assert daemon.stop() == 0


def test_http_control_listing_and_download(daemon_subprocess: StartDaemonSubprocess,
                                           tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    daemon = daemon_subprocess(f'[recorder]\ndirectory = "{rec}"\n'
                               '[security]\ntoken = "s3cret-t0ken"\n', args=("--sim",))
    assert daemon.get("/api/recordings")[1]["recordings"] == []
    status, _ = daemon.post("/api/record", {"enabled": True})
    assert status == 401
    status, body = daemon.post("/api/record", {"enabled": "yes"}, token="s3cret-t0ken")
    assert status == 422 and "enabled" in body["error"]
    status, body = daemon.post("/api/record", {"enabled": True}, token="s3cret-t0ken")
    assert status == 200 and body["recording"] is True

    def listed() -> dict[str, Any]:
        (entry,) = daemon.get("/api/recordings")[1]["recordings"]
        return entry  # type: ignore[no-any-return]

    entry = listed()
    assert entry["recording"] is True
    first = entry["size"]  # the writer flushes as it goes: wait until it wrote more
    wait_for(lambda: listed()["size"] > max(first, 0), "the recording growing", within_s=10)
    status, body = daemon.post("/api/record", {"enabled": False}, token="s3cret-t0ken")
    assert status == 200 and body["recording"] is False
    (entry,) = daemon.get("/api/recordings")[1]["recordings"]
    assert entry["complete"] is True and entry["duration_s"] > 0 and entry["start"] > 0
    with urllib.request.urlopen(f"{daemon.base_url}/api/recordings/{entry['name']}") as reply:
        assert reply.read() == (rec / entry["name"]).read_bytes()
    for name in ("..%2Fa-file", "..%2F..%2Fetc%2Fpasswd", "arbiterd-x.mcap%2F..%2F..%2Fx",
                 ".arbiterd-x.mcap", "arbiterd-nothing.mcap"):
        assert daemon.get(f"/api/recordings/{name}")[0] == 404, name
    assert daemon.stop() == 0


def test_links_and_odd_names_in_the_recordings_directory_are_not_served(
        daemon_subprocess: StartDaemonSubprocess, tmp_path: Path) -> None:
    """A symbolic link named like a recording (to /etc/passwd) was listed and served without
    a token; an over-long name answered 500 with a traceback (File name too long)."""
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "arbiterd-passwd.mcap").symlink_to("/etc/passwd")
    (rec / "arbiterd-dir.mcap").mkdir()
    os.mkfifo(rec / "arbiterd-fifo.mcap")
    (rec / "arbiterd-real.mcap").write_bytes(b"\x89MCAP0\r\n")
    daemon = daemon_subprocess(f'[recorder]\ndirectory = "{rec}"\n'
                               '[security]\ntoken = "s3cret-t0ken"\n')
    names = [r["name"] for r in daemon.get("/api/recordings")[1]["recordings"]]
    assert names == ["arbiterd-real.mcap"]
    for name in ("arbiterd-passwd.mcap", "arbiterd-dir.mcap", "arbiterd-fifo.mcap",
                 "arbiterd-" + "a" * 300 + ".mcap"):
        status, body = daemon.get(f"/api/recordings/{name}")
        assert status == 404 and len(body["error"]) < 120, (name, status, body)
    assert daemon.get("/api/recordings/arbiterd-real.mcap")[0] == 200
    assert "Traceback" not in daemon.log()
    assert daemon.stop() == 0
