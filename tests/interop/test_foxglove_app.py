# The real Foxglove Studio web app (@foxglove/studio-base 1.48.0's prebuilt bundle) in Debian's
# Chromium, WebGL through SwiftShader, against `arbiterd run --sim`: with [mapping] on its 3D
# panel, in frame `map`, receives /map and /scan and draws the map; in the apartment its publish
# tool, worked by the mouse, sends a goal on /goal_pose and the robot drives there.
from __future__ import annotations

import base64
import json
import math
import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from daemon.messages.cdr_read import decode
from slam.pose import compose
from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.net import free_port
from tests.support.wait import wait_for

HERE = Path(__file__).resolve().parent
NODE = shutil.which("node")
CHROMIUM = os.environ.get("ARBITERD_CHROMIUM", "/usr/bin/chromium")
PACKAGES = ("@foxglove/studio-base", "react", "react-dom", "playwright-core")
# Set to a file (e.g. docs/img/foxglove-3d-map.png) to keep the screenshot (not ARBITERD_*: the
# daemon reads those as config overrides, and [foxglove] is a section).
SHOT_TO = os.environ.get("FOXGLOVE_APP_SCREENSHOT")


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


def _run_app(node: str, daemon: DaemonSubprocess, shot: Path, *extra: str,
             foxglove_port: int | None = None) -> dict[str, dict[str, Any]]:
    """Runs foxglove_app.mjs against the daemon: its steps by name, once every step passed.
    With ``foxglove_port`` the app connects with "Foxglove WebSocket" to that port, else with
    "Rosbridge" to the daemon's rosbridge port."""
    url = f"ws://127.0.0.1:{foxglove_port or daemon.ws_port}/"
    env = {**os.environ, "FOXGLOVE_APP_SOURCE": "foxglove" if foxglove_port else ""}
    result = subprocess.run([node, str(HERE / "foxglove_app.mjs"), url, str(free_port()),
                             str(shot), *extra], cwd=HERE, capture_output=True, text=True,
                            timeout=300, env=env)
    steps: dict[str, dict[str, Any]] = {}
    for line in result.stdout.splitlines():
        if line.startswith("{"):
            record = json.loads(line)
            steps[record["step"]] = record
    assert result.returncode == 0 and "done" in steps, (
        f"{result.stdout}\n{result.stderr}\n--- daemon ---\n{daemon.log()}")
    return steps


@pytest.mark.timeout(330)  # the app loads 56 MB of JavaScript, SwiftShader renders on the CPU
@pytest.mark.parametrize("connection", ["rosbridge", "foxglove"])
def test_foxglove_3d_panel_shows_the_map_and_the_scan(tmp_path: Path, connection: str) -> None:
    """With either of the app's connections: "Rosbridge" on :9090's port, "Foxglove
    WebSocket" on [foxglove]'s."""
    node = _require_app()
    shot = tmp_path / "foxglove-3d-map.png"
    fox_port = free_port() if connection == "foxglove" else None
    toml = '[sim]\ndriver = "mock"\n[mapping]\nenabled = true\n' \
        f'directory = "{tmp_path / "maps"}"\n'
    if fox_port:
        toml += f'[foxglove]\nenabled = true\nhost = "127.0.0.1"\nport = {fox_port}\n'
    with DaemonSubprocess(tmp_path, toml, args=("--sim",)) as daemon:
        wait_for(lambda: daemon.get("/api/health")[1]["components"]["mapping"]
                 .get("maps_published", 0) > 0, "the first /map", within_s=30, interval_s=0.1)
        steps = _run_app(node, daemon, shot, foxglove_port=fox_port)
        health = daemon.get("/api/health")[1]["components"]
        assert daemon.stop() == 0
    if fox_port:  # the app's data came over the Foxglove WebSocket protocol
        fox = health["foxglove"]
        assert fox["connections"] >= 1 and fox["protocol_errors"] == 0, fox
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


APARTMENT_START = (-1.0, -2.5, 0.0)  # sim/worlds/apartment.toml; odom starts here
# in odom: the living room past the table, facing the bedrooms (world (0.0, -0.5)); the app
# looks down at TARGET, DISTANCE metres over the panel's height
# the position, then a point the heading faces (60 px clear of the panel's settings hint)
CLICKS = ((1.0, 2.0), (1.0, 2.6))
TARGET, DISTANCE = (0.5, 1.0), 6.0


@pytest.mark.timeout(330)
@pytest.mark.parametrize("connection", ["rosbridge", "foxglove"])
def test_a_goal_published_from_the_3d_panel_drives_the_robot_there(tmp_path: Path,
                                                                   connection: str) -> None:
    node = _require_app()
    fox_port = free_port() if connection == "foxglove" else None
    toml = '[sim]\ndriver = "mock"\nworld_file = "apartment"\n'
    if fox_port:
        toml += f'[foxglove]\nenabled = true\nhost = "127.0.0.1"\nport = {fox_port}\n'
    with DaemonSubprocess(tmp_path, toml, args=("--sim",)) as daemon:
        wait_for(lambda: daemon.get("/api/status")[1]["safety"]["zone"] != "unknown",
                 "the first revolution", within_s=30, interval_s=0.1)
        spec = {"api": daemon.base_url, "frame": "odom", "target": TARGET,
                "distance": DISTANCE, "clicks": CLICKS}
        steps = _run_app(node, daemon, tmp_path / "foxglove-goal.png", json.dumps(spec),
                         foxglove_port=fox_port)
        wait_for(lambda: abs(daemon.get("/api/status")[1]["ground_truth"]["v"]) < 0.01,
                 "the robot at rest", within_s=10, interval_s=0.1)
        truth = daemon.get("/api/status")[1]["ground_truth"]
        goal = daemon.get("/api/goal")[1]
        collisions = daemon.get("/api/sim/metrics")[1]["collisions"]
        log = daemon.log()
        assert daemon.stop() == 0
    print(json.dumps(steps, indent=1))  # shown when an assertion fails

    # (a) the app advertised its three publish topics (in the short spelling, without /msg/)
    # and published a PoseStamped in odom (over the Foxglove protocol: CDR, as a channel)
    published = steps["published"]
    advertised = {a["topic"]: a["type"] for a in published["advertised"]}
    assert advertised == {"/goal_pose": "geometry_msgs/PoseStamped",
                          "/clicked_point": "geometry_msgs/PointStamped",
                          "/initialpose": "geometry_msgs/PoseWithCovarianceStamped"}, advertised
    msg = published["msg"] if not fox_port else decode(
        "geometry_msgs/msg/PoseStamped", base64.b64decode(published["cdr"]))
    assert msg["header"]["frame_id"] == "odom", msg
    position, q = msg["pose"]["position"], msg["pose"]["orientation"]
    yaw = 2 * math.atan2(q["z"], q["w"])
    # where the mouse clicked: the 2D camera maps pixels to the scene within a pixel or two
    assert math.hypot(position["x"] - CLICKS[0][0], position["y"] - CLICKS[0][1]) < 0.1, msg
    assert abs(math.remainder(yaw - math.pi / 2, math.tau)) < 0.1, msg
    # the daemon took that goal, as sent, and only that one
    assert goal["goals"] == 1 and goal["goal"]["frame"] == "odom", goal
    assert goal["goal"]["x"] == pytest.approx(position["x"], abs=1e-9), goal
    assert goal["goal"]["y"] == pytest.approx(position["y"], abs=1e-9), goal
    assert goal["goal"]["theta"] == pytest.approx(yaw, abs=1e-6), goal
    # (b) the robot drove there: the goal in the world is where the robot truly is
    assert steps["navigation"]["goal"]["state"] == "succeeded", steps["navigation"]
    assert goal["state"] == "succeeded", goal
    x, y, theta = compose(APARTMENT_START, (position["x"], position["y"], yaw))
    assert math.hypot(truth["x"] - x, truth["y"] - y) <= 0.10, (truth, (x, y, theta))
    # the heading navigation holds to 0.1 rad is its odometry's; the true one differs by what
    # the simulator's encoder noise and slip did to that estimate (0.26 rad off in one CI run)
    assert abs(math.remainder(truth["theta"] - theta, math.tau)) <= 0.35, (truth, theta)
    assert collisions == 0
    # (c) no status error reached the app, nothing about an unknown type in its own lists
    app = steps["app"]
    # the watch sees the app's text traffic: rosapi replies, or parameter values
    seen = "parameterValues" if fox_port else "service_response"
    assert app["received"].get(seen, 0) >= 1, app
    assert app["statuses"] == [], app["statuses"]
    assert app["unknownType"] == [], app
    assert app["problems"]["lines"][:1] == ["No problems found"], app["problems"]
    assert "unknown message type" not in log
