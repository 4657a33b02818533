# The web console end to end: Debian's Chromium (playwright-core on Node) against
# `arbiterd run --sim`, driving with keys, joystick and touch; e-stop; token; a faulted driver;
# wander, explore, recorder, resets, log and health details; screenshots.
from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.wait import wait_for

HERE = Path(__file__).resolve().parent
NODE = shutil.which("node")
CHROMIUM = os.environ.get("ARBITERD_CHROMIUM", "/usr/bin/chromium")
# Set to a folder (e.g. docs) to keep the run's screenshots there as well.
SHOTS_TO = os.environ.get("ARBITERD_CONSOLE_SCREENSHOTS")
Steps = dict[str, dict[str, Any]]
# The mock driver's emulator: the console is under test here, not a serial link's timing (a
# starved serial emulator on a loaded machine is a real driver fault, and health answers 503).
SIM = '[sim]\ndriver = "mock"\n'


def _require_browser() -> None:
    """Node, Chromium and the locked playwright-core are prerequisites (`./install.sh test`)."""
    if NODE is None:
        pytest.fail("node is not installed; run ./install.sh test")
    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing; ./install.sh test installs Debian's chromium "
                    "(or set ARBITERD_CHROMIUM to a Chromium binary)")
    if not (HERE / "node_modules" / "playwright-core" / "package.json").exists():
        pytest.fail("tests/console/node_modules/playwright-core is missing; run `npm ci` in "
                    "tests/console (./install.sh dev does it)")


def _wait_healthy(daemon: DaemonSubprocess) -> None:
    wait_for(lambda: daemon.get("/api/health")[1].get("status") == "ok",
             "the simulated robot healthy (lidar streaming)", within_s=20)


def _keep_shots(shots: Path, *names: str) -> None:
    for name in names:
        assert (shots / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        if SHOTS_TO:
            shutil.copy(shots / name, Path(SHOTS_TO) / name)


def _run_console(daemon: DaemonSubprocess, *args: str, healthy: bool = True) -> Steps:
    if healthy:
        _wait_healthy(daemon)
    assert NODE is not None
    result = subprocess.run([NODE, str(HERE / "console_client.mjs"), daemon.base_url + "/",
                             *args], cwd=HERE, capture_output=True, text=True, timeout=170)
    steps = {}
    for line in result.stdout.splitlines():
        if line.startswith("{"):
            record = json.loads(line)
            steps[record["step"]] = record
    assert result.returncode == 0 and "done" in steps, (
        f"console client failed:\n{result.stdout}\n{result.stderr}\n--- daemon log ---\n"
        f"{daemon.log()}")
    return steps


def moved(step: dict[str, Any], end: str = "atRelease") -> float:
    a, b = step["before"], step[end]
    return math.hypot(b["x"] - a["x"], b["y"] - a["y"])


def ahead(step: dict[str, Any], end: str) -> float:
    """Distance travelled along the robot's heading at the start."""
    a, b = step["before"], step[end]
    return (b["x"] - a["x"]) * math.cos(a["theta"]) + (b["y"] - a["y"]) * math.sin(a["theta"])


def stopped_by_zero_command(phase: dict[str, Any]) -> bool:
    """Still, and the page's zero command stopped it, not the deadman."""
    return bool(phase["still"] and phase["zeroCommanded"]
                and not any(r.startswith("deadman") for r in phase["reasons"]))


def test_console_drives_the_simulated_robot(tmp_path: Path) -> None:
    _require_browser()
    shots = tmp_path / "screenshots"
    shots.mkdir()
    with DaemonSubprocess(tmp_path, SIM, args=("--sim",)) as daemon:
        steps = _run_console(daemon, "drive", "--shots", str(shots))
        assert daemon.stop() == 0
        log = daemon.log()
    loaded = steps["loaded"]
    assert loaded["errors"] == [] and loaded["conn"] == "connected", log
    assert {"control", "lidar", "rosbridge", "http", "sim"} <= set(loaded["components"])
    assert loaded["health"] == "ok" and loaded["mode"] == "simulated robot"
    assert int(loaded["scan"].split("scan ")[1].split()[0]) > 50
    view = steps["view"]  # the default view fits the scan: the arena's walls are in it
    assert view["scanHalfWidth"] <= view["halfWidth"] and \
        view["scanHalfHeight"] <= view["halfHeight"], view
    assert view["scanHalfHeight"] > 4.0 and "(fit)" in view["info"], view  # wider than 8 m
    assert view["hint"] is True  # a laptop has keys

    forward = steps["forward"]
    assert ahead(forward, "atRelease") >= 0.2
    held = forward["held"]["reasons"]  # steady commands while held: no deadman mid-drive
    assert "command" in held and not any(r.startswith("deadman") for r in held)
    assert stopped_by_zero_command(forward["stop"])
    assert steps["left"]["atRelease"]["theta"] - steps["left"]["before"]["theta"] > 0.1
    assert steps["right"]["atRelease"]["theta"] - steps["right"]["before"]["theta"] < -0.1
    assert stopped_by_zero_command(steps["left"]["stop"])
    assert stopped_by_zero_command(steps["right"]["stop"])

    joystick = steps["joystick"]
    assert ahead(joystick, "atHide") >= 0.2
    assert stopped_by_zero_command(joystick["hidden"])

    estop = steps["estop"]
    assert estop["engaged"] is True and "ENGAGED" in estop["shown"]
    assert moved(estop["blocked"]) < 0.01
    assert all(r.startswith("e-stop") for r in estop["blocked"]["held"]["reasons"])
    assert steps["release"] == {"step": "release", "afterClick": True, "afterHold": False}
    assert steps["errors"]["errors"] == [], log

    touch = steps["touch"]
    assert ahead(touch, "atRelease") >= 0.2 and stopped_by_zero_command(touch["stop"])
    assert touch["errors"] == [], log
    assert touch["hint"] is False and steps["narrow"]["hint"] is False  # no keys on a phone
    _keep_shots(shots, "console-laptop.png", "console-phone.png")


def test_console_with_a_token(tmp_path: Path) -> None:
    _require_browser()
    with DaemonSubprocess(tmp_path, SIM + '[security]\ntoken = "console-t0ken"\n',
                       args=("--sim",)) as daemon:
        steps = _run_console(daemon, "token", "--token", "console-t0ken")
        assert daemon.stop() == 0
    without = steps["without"]
    assert "needs a token" in without["asked"]
    assert without["access"] == "read-only: token needed"
    assert "needs a token to drive" in without["banner"]
    assert "not sent: this robot needs a token" in without["command"]
    assert moved(without["moved"]) < 0.01
    estop = steps["estopWithout"]  # anyone may stop the robot; releasing needs the token
    assert estop["latched"] is True and estop["afterHold"] is True, estop
    assert "releasing it needs the token" in estop["shown"] and estop["pageErrors"] == [], estop
    assert "needs a token to drive" in estop["banner"], estop
    wrong = steps["wrong"]
    assert wrong["access"] == "token refused" and "token was refused" in wrong["banner"]
    assert moved(wrong["moved"]) < 0.01
    right = steps["with"]
    assert right["access"] == "can drive" and right["banner"] == ""
    assert ahead(right["moved"], "atRelease") >= 0.2 and right["stored"] is True
    assert right["estop"] is True  # the e-stop goes over HTTP with the Bearer token


def test_console_says_it_lost_the_robot_and_reconnects(tmp_path: Path) -> None:
    _require_browser()
    assert NODE is not None
    with DaemonSubprocess(tmp_path, SIM, args=("--sim",)) as daemon:
        _wait_healthy(daemon)
        client = subprocess.Popen([NODE, str(HERE / "console_client.mjs"),
                                   daemon.base_url + "/", "reconnect"], cwd=HERE,
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            steps = _follow(client, daemon)
        finally:
            client.kill()
    assert client.wait(10) == 0 and "done" in steps, steps
    assert steps["lost"]["conn"] == "disconnected"
    assert "Disconnected: the robot at 127.0.0.1" in steps["lost"]["banner"]
    back = steps["back"]
    assert back["conn"] == "connected" and back["bannerHidden"] is True
    assert ahead(back["drove"], "atRelease") >= 0.2


def _follow(client: subprocess.Popen[str], daemon: DaemonSubprocess) -> Steps:
    """The client's steps; stops the daemon when the page is ready, restarts it once lost."""
    steps: Steps = {}
    assert client.stdout is not None
    for line in client.stdout:
        if not line.startswith("{"):
            continue
        record = json.loads(line)
        steps[record["step"]] = record
        if record["step"] == "ready":
            assert daemon.stop() == 0  # the robot goes away...
        elif record["step"] == "lost":
            daemon.start()  # ...and comes back on the same ports
            _wait_healthy(daemon)
    return steps


def test_console_shows_a_faulted_robot(tmp_path: Path) -> None:
    """The serial driver's port does not exist: health 503, commands 409. The page must say
    so at the top and must not look drivable."""
    _require_browser()
    shots = tmp_path / "screenshots"
    shots.mkdir()
    port = "/dev/ttyACM-absent"  # short, like a real one, and never there
    toml = (f'[driver]\ntype = "serial"\n[driver.serial]\nport = "{port}"\n'
            '[lidar]\nenabled = false\n')
    with DaemonSubprocess(tmp_path, toml, use_mock_log=False) as daemon:
        assert daemon.get("/api/health")[0] == 503
        steps = _run_console(daemon, "fault", "--shots", str(shots), healthy=False)
        assert daemon.post("/api/cmd_vel", {"linear": {"x": 0.2}})[0] == 409
        assert daemon.stop() == 0
        log = daemon.log()
    for step in (steps["fault"], steps["faultPhone"]):
        assert step["conn"] == "connected" and step["health"] == "error", step
        assert step["access"] == "cannot drive: driver fault" and step["accessState"] == "fault"
        assert step["bannerKind"] == "fault", step
        assert step["banner"].startswith("Driver fault: serial driver not available"), step
        assert port in step["banner"] and step["pageErrors"] == [], step
    fault = steps["fault"]
    assert "not sent: driver fault" in fault["command"], fault
    assert "fault: serial driver not available" in fault["control"]
    assert steps["faultPhone"]["bannerTop"] < 200  # above the fold, under the top bar
    assert "/stamped_cmd_vel" not in log  # nothing was sent to be refused
    _keep_shots(shots, "console-fault-laptop.png", "console-fault-phone.png")


def test_console_controls_beyond_driving(tmp_path: Path) -> None:
    _require_browser()
    shots = tmp_path / "screenshots"
    shots.mkdir()
    toml = SIM + f'[recorder]\ndirectory = "{tmp_path / "recordings"}"\nflush_interval_s = 0.2\n'
    with DaemonSubprocess(tmp_path, toml, args=("--sim",)) as daemon:
        steps = _run_console(daemon, "controls", "--shots", str(shots))
        recordings = daemon.get("/api/recordings")[1]["recordings"]
        assert daemon.stop() == 0
        log = daemon.log()
    controls = steps["controls"]
    assert controls["errors"] == [], log
    assert controls["wanderOn"].startswith("wander · "), controls
    assert controls["exploreOn"].startswith("explore · exploring · "), controls
    assert controls["exploreMode"] in ("explore", "off"), controls  # it may be done already
    assert ".mcap · " in controls["recordState"], controls
    health = controls["health"]
    assert "nearest obstacle" in health["collision_monitor"], health
    assert health["recorder"].startswith("recording arbiterd-"), health
    assert health["autonomy"].startswith("mode "), health
    assert controls["magic"] == "\x89MCAP0\r\n" and len(recordings) == 1, recordings
    assert math.hypot(controls["moved"]["x"], controls["moved"]["y"]) > 0.1
    assert math.hypot(controls["afterOdom"]["x"], controls["afterOdom"]["y"]) < 0.05
    truth, pose = controls["truth"], controls["afterSim"]
    assert math.hypot(truth["x"], truth["y"]) < 0.05  # back at the start...
    assert math.hypot(pose["x"] - truth["x"], pose["y"] - truth["y"]) < 0.05  # ...odometry too
    assert controls["logLines"] > 0 and "simulation reset" in controls["message"]
    assert "odometry reset to" in log and "flight recorder: writing" in log
    assert "autonomy wander (requested over HTTP)" in log
    assert "autonomy explore (requested over HTTP)" in log
    phone = steps["controlsPhone"]
    assert phone["hint"] is False and phone["errors"] == [], phone
    _keep_shots(shots, "console-controls-laptop.png", "console-controls-phone.png")


def test_console_draws_the_map_saves_it_and_sets_the_pose(tmp_path: Path) -> None:
    """[mapping] on: the console draws the grid under the scan in the map frame, its Save map
    button writes a map that GET /api/maps lists (and shows a refusal's text), and in
    localisation mode a drag on the view sends the pose that health then reports."""
    _require_browser()
    assert NODE is not None
    shots = tmp_path / "screenshots"
    shots.mkdir()
    toml = SIM + f'[mapping]\nenabled = true\ndirectory = "{tmp_path / "maps"}"\n'
    with DaemonSubprocess(tmp_path, toml, args=("--sim",)) as daemon:
        _wait_healthy(daemon)
        client = subprocess.Popen([NODE, str(HERE / "console_client.mjs"),
                                   daemon.base_url + "/", "mapping", "--shots", str(shots),
                                   "--map-name", "console-map"], cwd=HERE,
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        steps: Steps = {}
        listed: list[str] = []
        try:
            assert client.stdout is not None
            for line in client.stdout:
                if not line.startswith("{"):
                    continue
                record = json.loads(line)
                steps[record["step"]] = record
                if record["step"] == "saved":  # localise in the map the button saved
                    listed = [m["name"] for m in daemon.get("/api/maps")[1]["maps"]]
                    x, y, deg = daemon.get("/api/health")[1]["components"]["mapping"]["pose"]
                    status, body = daemon.post("/api/map/load", {  # a new mapper process
                        "name": "console-map", "pose": {"x": x, "y": y, "heading_deg": deg}},
                        timeout=30)
                    assert status == 200 and body["mode"] == "localize", body
        finally:
            client.kill()
        assert client.wait(10) == 0 and "done" in steps, (steps.get("fail"), daemon.log())
        sent = steps["pose"]["sent"]
        revolutions = steps["pose"]["before"]["revolutions"]

        def reported() -> dict[str, Any] | None:
            mapping = daemon.get("/api/health")[1]["components"]["mapping"]
            return mapping if mapping["revolutions"] > revolutions + 2 else None

        after = wait_for(reported, "revolutions matched after the dragged pose", within_s=10,
                          interval_s=0.1)
        log = daemon.log()
        assert daemon.stop() == 0
    drawn = steps["map"]
    assert drawn["cells"] > 20 and drawn["version"] > 0, drawn
    assert drawn["occupied"] > 50, drawn  # the walls' cells, where the scan is not on them
    assert drawn["free"] > drawn["occupied"], drawn  # the free space the lidar saw, light
    assert drawn["saveShown"] is True and drawn["hintShown"] is False, drawn
    save = steps["save"]
    assert save["refused"]["kind"] == "error" and "is not a map name" in save["refused"]["text"]
    assert save["saved"] == {"kind": "info", "text": save["saved"]["text"]}, save
    assert save["saved"]["text"].startswith("map saved: console-map.yaml + console-map.pgm")
    assert "console-map" in listed and (tmp_path / "maps" / "console-map.pgm").is_file()
    pose = steps["pose"]
    target = pose["target"]  # where the test pressed, and the heading it dragged towards
    # within a few pixels of the press (0.034 m once in CI)
    assert math.hypot(sent["x"] - target["x"], sent["y"] - target["y"]) < 0.05, pose
    assert abs(math.remainder(sent["theta"] - target["theta"], math.tau)) < math.radians(3)
    assert pose["message"].startswith("pose set to") and pose["hintShown"] is True, pose
    # the browser's own line for the refused name's 422 is expected; nothing else
    assert [e for e in pose["errors"] if "status of 422" not in e] == [], log
    assert (f"pose in the map set to ({sent['x']:.2f} m, {sent['y']:.2f} m, "
            f"{math.degrees(sent['theta']):.0f} deg)") in log
    x, y, deg = after["pose"]  # matched from the sent pose: it stays near it (0.22 m off truth)
    assert math.hypot(x - sent["x"], y - sent["y"]) < 0.35, (after, sent)
    assert abs(math.remainder(math.radians(deg) - sent["theta"], math.tau)) < math.radians(25)
    _keep_shots(shots, "console-map.png")


def test_console_sends_a_tapped_goal_and_the_robot_arrives(tmp_path: Path) -> None:
    """[navigation] on: the figure-eight starts from its button (its plan drawn) and its cancel
    stops it; the "go to" tool and a tap on the view send the goal there (odometry frame, no
    heading), the plan is drawn, the state line follows until the robot is there (ground
    truth); with [arm] on, the fetch tool's two taps send a fetch and its cancel ends it."""
    _require_browser()
    assert NODE is not None
    start, goal = (-1.0, -2.5), (0.0, -0.5)  # sim/worlds/apartment.toml: past the table
    target = (goal[0] - start[0], goal[1] - start[1])  # in the odometry frame (heading 0)
    toml = '[sim]\ndriver = "mock"\nworld_file = "apartment"\n[arm]\nenabled = true\n'
    fetch = (0.0, 0.0, *target)  # from the start point to where the goal took the robot
    with DaemonSubprocess(tmp_path, toml, args=("--sim",)) as daemon:
        _wait_healthy(daemon)
        client = subprocess.run([NODE, str(HERE / "console_client.mjs"), daemon.base_url + "/",
                                 "navigate", "--goal", f"{target[0]},{target[1]}",
                                 "--fetch", ",".join(map(str, fetch))], cwd=HERE,
                                capture_output=True, text=True, timeout=180, check=False)
        steps = {r["step"]: r for r in map(json.loads, filter(
            lambda line: line.startswith("{"), client.stdout.splitlines()))}
        assert client.returncode == 0 and "done" in steps, (client.stdout, client.stderr,
                                                             daemon.log())
        collisions = daemon.get("/api/sim/metrics")[1]["collisions"]
        assert daemon.stop() == 0
    sent = steps["goal"]["sent"]
    assert sent["frame"] == "odom" and "theta" not in sent, sent
    assert math.hypot(sent["x"] - target[0], sent["y"] - target[1]) < 0.05, sent
    reached = steps["goal"]
    assert reached["pressed"] == "true" and reached["planPoints"] > 1, reached
    assert reached["following"].startswith(("planning", "following")), reached
    assert reached["cancelShown"] is True and reached["reached"].startswith("succeeded"), reached
    assert reached["toolAfter"] == "false" and reached["planAfter"] == "0", reached
    figure = steps["figure"]
    assert figure["planPoints"] > 100 and figure["state"].startswith("canceled"), figure
    assert figure["cancelShown"] is False and reached["errors"] == [], (figure, reached)
    assert collisions == 0
    truth = reached["truth"]  # when the console said succeeded
    assert math.hypot(truth["x"] - goal[0], truth["y"] - goal[1]) <= 0.10, truth
    # the fetch tool: the object's tap, then the drop's, sent both; cancel fetch ended it
    fetched = steps["fetch"]
    assert fetched["pressed"] == "true" and fetched["prompt"] == "now tap where to drop it"
    for key, (x, y) in (("object", fetch[:2]), ("drop", fetch[2:])):
        assert math.hypot(fetched["sent"][key][0] - x, fetched["sent"][key][1] - y) < 0.05, fetched
    assert fetched["running"].startswith("fetch: NAV_TO_OBJECT") and fetched["cancelShown"]
    assert fetched["ended"].startswith("fetch canceled · NAV_TO_OBJECT: canceled over HTTP")
    assert fetched["api"]["result"] == "canceled" and fetched["toolAfter"] == "false", fetched


def test_console_moves_the_arm(tmp_path: Path) -> None:
    """[arm] on (PCA9685 emulated): the pose buttons move the arm and the side view follows;
    the gripper closes; the panel fits a phone."""
    _require_browser()
    shots = tmp_path / "screenshots"
    shots.mkdir()
    # no lidar: the arm panel is under test, and the daemon is up sooner without it
    toml = '[sim]\ndriver = "mock"\nlidar = false\n[arm]\nenabled = true\n' \
        'backend = "pca9685"\nmax_speed = [10.0, 10.0, 10.0, 0.35]\n'
    with DaemonSubprocess(tmp_path, toml, args=("--sim",)) as daemon:
        steps = _run_console(daemon, "arm", "--shots", str(shots), healthy=False)
        assert daemon.stop() == 0
        log = daemon.log()
    arm = steps["arm"]
    assert arm["errors"] == [], log
    assert arm["poses"] == ["carry", "grasp", "grasp_close", "home", "pregrasp"]
    assert arm["at"]["api"]["pose"] == "pregrasp" and "at pregrasp" in arm["at"]["state"]
    tip = arm["at"]["points"].split()[-1].split(",")
    assert (float(tip[0]), -float(tip[1])) == pytest.approx((0.7736, -0.0381), abs=1e-3)
    assert arm["before"] != arm["at"]["points"]
    assert arm["closed"] == 0.0 and "close the gripper" in arm["message"]
    phone = steps["armPhone"]
    assert phone["errors"] == [] and phone["width"] <= 390
    _keep_shots(shots, "console-arm-laptop.png", "console-arm-phone.png")
