# Real rclpy nodes of two ROS 2 releases (Kilted, Jazzy) against the face, each in its own venv.
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from daemon.messages.typehash import type_hash
from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.paths import REPO
from tests.support.ros2_probe import ros_env

TOKEN = "ros2-peer-test-token"
DOMAIN = 44
PEER = REPO / "tests" / "ros2_netns" / "rclpy_peer.py"
#: set by the ROS wheels' start-up hook (ros_wheels_bootstrapper) for the venv it runs in
LEAKED = ("LD_LIBRARY_PATH", "_ROS_WHEELS_BOOTSTRAP_COMPLETE", "AMENT_PREFIX_PATH", "PYTHONPATH")
#: the interpreter of the venv with Kilted's rclpy (made by ./install.sh dev; see the caller)
KILTED_PYTHON = os.environ.get("ARBITERD_KILTED_PYTHON", "")


def start_daemon(tmp_path: Path, distro: str) -> DaemonSubprocess:
    toml = (f'[security]\ntoken = "{TOKEN}"\n'
            f'[ros2]\nenabled = true\ndomain_id = {DOMAIN}\ndiscovery = "localhost"\n'
            f'distro = "{distro}"\nallow_commands = true\ncommand_timeout = 0.5\n')
    return DaemonSubprocess(tmp_path, toml, args=("--sim",))


def run_peer(python: str, drive_m: float) -> tuple[dict[str, Any], str]:
    """The peer's report and its stderr (where rcutils logs its warnings)."""
    result = subprocess.run([python, str(PEER), "--drive", str(drive_m)], cwd=REPO, text=True,
                            capture_output=True, timeout=90, check=False,
                            env={**peer_env(), **ros_env(DOMAIN)})
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-4000:]
    return json.loads(result.stdout.strip().splitlines()[-1]), result.stderr


def peer_env() -> dict[str, str]:
    """This environment without what the ROS wheels' bootstrap set for this venv's release
    (its library path; the flag that it ran): the peer's venv sets its own."""
    return {key: value for key, value in os.environ.items() if key not in LEAKED}


def truth(daemon: DaemonSubprocess) -> dict[str, float]:
    _, status = daemon.get("/api/status", token=TOKEN)
    return dict(status["ground_truth"])


def scan_rays(daemon: DaemonSubprocess) -> int:
    _, scan = daemon.get("/api/scan", token=TOKEN)
    return len(scan["ranges_m"] if "ranges_m" in scan else scan["ranges"])


def hash_warnings(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "hash" in line.lower()]


def check_peer(tmp_path: Path, distro: str, python: str) -> dict[str, Any]:
    """The peer of ``distro`` reads /scan (every ray) and /odom, sees the face's type hash
    equal to its own for /scan and /cmd_vel, drives the robot, and logs no type-hash
    warning."""
    with start_daemon(tmp_path, distro) as daemon:
        start = truth(daemon)
        report, stderr = run_peer(python, drive_m=0.1)
        after = truth(daemon)
        assert report["scans"] >= 2 and report["odoms"] >= 1, report
        assert report["rays"] == scan_rays(daemon) > 0
        scan = {"type": "sensor_msgs/msg/LaserScan", "hash": type_hash("sensor_msgs/msg/LaserScan")}
        twist = {"type": "geometry_msgs/msg/Twist", "hash": type_hash("geometry_msgs/msg/Twist")}
        assert [_typed(e) for e in report["scan_own"]] == [scan]
        assert report["scan_writers"] and all(_typed(e) == scan for e in report["scan_writers"])
        assert report["cmd_vel_readers"]
        assert all(_typed(e) == twist for e in report["cmd_vel_readers"])
        _, health = daemon.get("/api/health", token=TOKEN)
        why = json.dumps([report, health["components"]["ros2"], stderr[-2000:]])
        assert report["driven"] > 0, why
        assert math.hypot(after["x"] - start["x"], after["y"] - start["y"]) > 0.08, why
        assert hash_warnings(stderr) == [], stderr[-4000:]
    return report


def _typed(endpoint: dict[str, str]) -> dict[str, str]:
    return {"type": endpoint["type"], "hash": endpoint["hash"]}


def test_a_kilted_node_reads_the_scan_and_drives(tmp_path: Path) -> None:
    if not KILTED_PYTHON:
        pytest.skip("no venv with ROS 2 Kilted's rclpy (ARBITERD_KILTED_PYTHON)")
    report = check_peer(tmp_path, "kilted", KILTED_PYTHON)
    assert report["rmw"] == "rmw_fastrtps_cpp"


def test_a_jazzy_node_reads_the_scan_and_drives_without_warnings(tmp_path: Path) -> None:
    report = check_peer(tmp_path, "jazzy", sys.executable)
    assert {e["node"] for e in report["scan_writers"] + report["cmd_vel_readers"]} == {"arbiterd"}
