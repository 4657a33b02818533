# Foxglove's own client stack (as its Rosbridge player uses it) against `arbiterd run --sim`:
# cbor-raw decoded with the advertised definitions equals the JSON path; roslib's cbor mode too.
from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from tests.support.daemon_subprocess import StartDaemonSubprocess

HERE = Path(__file__).resolve().parent
NODE = shutil.which("node")
TOPICS = ("/odom", "/scan", "/tf", "/robot_info", "/rosout", "/latency_reports")
PACKAGES = ("@foxglove/roslibjs", "@foxglove/rosmsg", "@foxglove/rosmsg2-serialization",
            "roslib")


def _require_node_packages() -> str:
    """Node and the locked packages are prerequisites (`./install.sh dev` runs `npm ci`)."""
    if NODE is None:
        pytest.fail("node is not installed; run ./install.sh dev")
    for package in PACKAGES:
        if not (HERE / "node_modules" / package / "package.json").exists():
            pytest.fail(f"tests/interop/node_modules/{package} is missing; run `npm ci` in "
                        "tests/interop (./install.sh dev does it)")
    return NODE


def _run_player(url: str) -> tuple[subprocess.CompletedProcess[str], list[dict[str, Any]]]:
    node = _require_node_packages()
    result = subprocess.run([node, str(HERE / "foxglove_player.mjs"), url], cwd=HERE,
                            capture_output=True, text=True, timeout=90)
    steps = [json.loads(line) for line in result.stdout.splitlines() if line.startswith("{")]
    return result, steps


def test_foxglove_player_decodes_cbor_raw_as_the_json_path_delivers(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    daemon = daemon_subprocess(args=("--sim",))
    result, steps = _run_player(f"ws://127.0.0.1:{daemon.ws_port}/")
    assert result.returncode == 0, (
        f"player failed:\n{result.stdout}\n{result.stderr}\n--- daemon ---\n{daemon.log()}")
    by_step: dict[str, list[dict[str, Any]]] = {}
    for step in steps:
        by_step.setdefault(step["step"], []).append(step)
    assert by_step["discovery"][0]["ros2"] is True
    compared = {(s["mode"], s["topic"]): s for s in by_step["compared"]}
    for mode in ("raw", "cbor"):  # cbor-raw through the player's readers; roslib's cbor mode
        for topic in TOPICS:
            entry = compared[(mode, topic)]
            assert entry["matched"] >= (1 if topic == "/robot_info" else 2), entry
            assert entry["problems"] == [], entry
    assert compared[("raw", "/scan")]["type"] == "sensor_msgs/msg/LaserScan"
    clock = by_step["clock"][0]  # secs/nsecs: the server clock at send
    assert abs(clock["skew_s"]) < 30 and clock["secs"] > 0
    assert by_step["foxglove_stamp"][0]["relayed"] == {"sec": 1700000000, "nanosec": 123456789}
    assert by_step["done"][0]["ok"] is True
    assert time.time() > 0 and daemon.stop() == 0
