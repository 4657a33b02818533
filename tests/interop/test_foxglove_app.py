# The real Foxglove Studio web app (@foxglove/studio-base 1.48.0's prebuilt bundle) in Debian's
# Chromium, WebGL through SwiftShader, against `arbiterd run --sim` with [mapping] on: its 3D
# panel, in frame `map`, receives /map and /scan and draws the map.
from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.net import free_port
from tests.support.wait import wait_for

HERE = Path(__file__).resolve().parent
NODE = shutil.which("node")
CHROMIUM = os.environ.get("ARBITERD_CHROMIUM", "/usr/bin/chromium")
PACKAGES = ("@foxglove/studio-base", "react", "react-dom", "playwright-core")
# Set to a file (e.g. docs/img/foxglove-3d-map.png) to keep the screenshot.
SHOT_TO = os.environ.get("ARBITERD_FOXGLOVE_SCREENSHOT")


def _require_app() -> str:
    if NODE is None:
        pytest.fail("node is not installed; run ./install.sh dev")
    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing; ./install.sh test installs Debian's chromium "
                    "(or set ARBITERD_CHROMIUM to a Chromium binary)")
    for package in PACKAGES:
        if not (HERE / "node_modules" / package / "package.json").exists():
            pytest.fail(f"tests/interop/node_modules/{package} is missing; run `npm ci` in "
                        "tests/interop (./install.sh dev does it)")
    return NODE


@pytest.mark.timeout(330)  # the app loads 56 MB of JavaScript, SwiftShader renders on the CPU
def test_foxglove_3d_panel_shows_the_map_and_the_scan(tmp_path: Path) -> None:
    node = _require_app()
    shot = tmp_path / "foxglove-3d-map.png"
    toml = '[sim]\ndriver = "mock"\n[mapping]\nenabled = true\n' \
        f'directory = "{tmp_path / "maps"}"\n'
    with DaemonSubprocess(tmp_path, toml, args=("--sim",)) as daemon:
        wait_for(lambda: daemon.get("/api/health")[1]["components"]["mapping"]
                 .get("maps_published", 0) > 0, "the first /map", within_s=30, interval_s=0.1)
        result = subprocess.run([node, str(HERE / "foxglove_app.mjs"),
                                 f"ws://127.0.0.1:{daemon.ws_port}/", str(free_port()),
                                 str(shot)], cwd=HERE, capture_output=True, text=True,
                                timeout=300)
        log = daemon.log()
        assert daemon.stop() == 0
    steps: dict[str, dict[str, Any]] = {}
    for line in result.stdout.splitlines():
        if line.startswith("{"):
            record = json.loads(line)
            steps[record["step"]] = record
    assert result.returncode == 0 and "done" in steps, (
        f"{result.stdout}\n{result.stderr}\n--- daemon ---\n{log}")
    assert steps["webgl"]["renderer"], steps["webgl"]  # WebGL 2 works (SwiftShader)
    topics = steps["topics"]["topics"]  # the app's own table: datatype, messages received
    assert topics["/map"]["type"] == "nav_msgs/msg/OccupancyGrid", topics
    assert topics["/scan"]["type"] == "sensor_msgs/msg/LaserScan", topics
    assert topics["/map"]["received"] >= 1 and topics["/scan"]["received"] >= 3, topics
    rendered = steps["rendered"]
    counts = rendered["counts"]
    # the map: its unknown cells grey and the free space the lidar swept light grey; the
    # occupied cells lie under /scan's red points, drawn on top of the map
    assert counts["unknown"] > 0.1 * counts["pixels"], rendered
    assert counts["free"] > 0.02 * counts["pixels"], rendered
    assert counts["scan"] > 100, rendered
    assert rendered["unknownType"] == [], rendered
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    if SHOT_TO:
        shutil.copy(shot, SHOT_TO)
