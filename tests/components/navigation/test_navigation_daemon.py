# `arbiterd run --sim`: a goal published on /goal_pose over rosbridge the way Foxglove does drives
# the robot there (ground truth); bad goals over rosbridge and HTTP are refused; it keeps running;
# `arbiterd mission FILE` runs a mission file's steps on it, and names a bad step.
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from daemon.messages.definitions import POINT_STAMPED, POSE_STAMPED, POSE_WITH_COVARIANCE_STAMPED
from slam.pose import between
from tests.support.daemon_subprocess import DaemonSubprocess, StartDaemonSubprocess
from tests.support.net import http
from tests.support.paths import REPO
from tests.support.rosbridge import Client, connect
from tests.support.wait import wait_for

START = (-1.0, -2.5, 0.0)  # sim/worlds/apartment.toml
GOAL = (0.0, -0.5, math.pi / 2)  # the living room, past the table, in the world's frame
WALL = (1.0, -3.0)  # on the wall between the living room and the kitchen


def pose_stamped(frame: str, x: float, y: float, yaw: float) -> dict[str, Any]:
    return {"header": {"frame_id": frame},
            "pose": {"position": {"x": x, "y": y, "z": 0.0},
                     "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2),
                                     "w": math.cos(yaw / 2)}}}


def status(daemon: DaemonSubprocess) -> dict[str, Any]:
    code, body = daemon.get("/api/status")
    assert code == 200, body
    return body  # type: ignore[no-any-return]


async def advertise_like_foxglove(client: Client) -> None:
    """What Foxglove's 3D panel advertises on every connection."""
    for topic, type_name in (("/goal_pose", POSE_STAMPED), ("/clicked_point", POINT_STAMPED),
                             ("/initialpose", POSE_WITH_COVARIANCE_STAMPED)):
        await client.send(op="advertise", topic=topic, type=type_name)
    await client.send(op="publish", topic="/clicked_point", id="click", msg={
        "header": {"frame_id": "odom"}, "point": {"x": 1.0, "y": 0.0, "z": 0.0}})


def state_is(name: str) -> Any:
    def matches(m: dict[str, Any]) -> bool:
        return m.get("topic") == "/navigation/state" and \
            json.loads(m["msg"]["data"])["state"] == name
    return matches


async def test_a_goal_from_foxglove_drives_the_robot_there(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    daemon = daemon_subprocess('[sim]\ndriver = "mock"\nworld_file = "apartment"\n',
                               args=("--sim",))
    wait_for(lambda: status(daemon)["safety"]["zone"] != "unknown", "the first revolution")
    async with connect(f"ws://127.0.0.1:{daemon.ws_port}") as client:
        for topic in ("/navigation/state", "/plan"):
            await client.send(op="subscribe", topic=topic)
        await advertise_like_foxglove(client)
        await client.send(op="publish", topic="/goal_pose", id="bad",
                          msg=pose_stamped("base_link", 1.0, 0.0, 0.0))
        refusal = await client.op("status", id="bad")
        assert refusal["level"] == "error" and "goal refused" in refusal["msg"], refusal

        x, y, yaw = between(START, GOAL)
        await client.send(op="publish", topic="/goal_pose", id="go",
                          msg=pose_stamped("odom", x, y, yaw))
        plan = await client.expect(lambda m: m.get("topic") == "/plan", what="/plan")
        assert plan["msg"]["header"]["frame_id"] == "odom" and plan["msg"]["poses"]
        await client.expect(state_is("succeeded"), within=60, what="the goal reached")
        errors = [m for m in client.received if m.get("op") == "status"
                  and m.get("level") == "error" and m.get("id") != "bad"]
        assert not errors, errors  # the three advertises and the ignored click included

    wait_for(lambda: abs(status(daemon)["ground_truth"]["v"]) < 0.01, "the robot at rest")
    truth = status(daemon)["ground_truth"]
    assert math.hypot(truth["x"] - GOAL[0], truth["y"] - GOAL[1]) <= 0.10, truth
    assert abs(math.remainder(truth["theta"] - GOAL[2], math.tau)) <= 0.1, truth
    assert daemon.get("/api/sim/metrics")[1]["collisions"] == 0
    assert status(daemon)["navigation"]["state"] == "succeeded"

    wall = between(START, (*WALL, 0.0))
    for body, code, problem in (({"x": wall[0], "y": wall[1]}, 409, "inside an obstacle"),
                                ({"x": 1.0, "y": "up"}, 422, "y: expected a finite number"),
                                ({"x": 1.0, "y": 0.0, "frame": "map"}, 409,
                                 "needs [mapping] enabled"),
                                ({"x": 500.0, "y": 0.0}, 409, "outside the map")):
        answer = daemon.post("/api/goal", body)
        assert answer[0] == code and problem in answer[1]["error"], answer
    code, body = daemon.post("/api/goal", {"x": 0.0, "y": 0.0})
    assert code == 200 and body["state"] == "planning", body
    code, body = daemon.post("/api/goal", {"path": "figure_eight", "size": 1.0})
    assert code == 200 and body["state"] == "following" and body["goals"] == 3, body
    code, body = http("DELETE", daemon.base_url + "/api/goal")
    assert code == 200 and body["state"] == "canceled", body
    wait_for(lambda: abs(status(daemon)["ground_truth"]["v"]) < 0.01, "the robot stopped")
    health = daemon.get("/api/health")
    assert health[0] == 200 and "navigation" in health[1]["components"], health


def test_exploring_over_http_drives_to_frontiers_until_switched_off(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    daemon = daemon_subprocess('[sim]\ndriver = "mock"\nworld_file = "apartment"\n',
                               args=("--sim",))
    wait_for(lambda: status(daemon)["safety"]["zone"] != "unknown", "the first revolution")
    code, body = daemon.post("/api/autonomy", {"mode": "explore"})
    assert code == 200 and body["mode"] == "explore", body
    assert body["exploration"]["state"] == "exploring", body

    def exploring() -> dict[str, Any] | None:
        explored = daemon.get("/api/autonomy")[1]["exploration"]
        return explored if explored["goals"] >= 2 and explored["explored_m2"] > 10 else None

    explored = wait_for(exploring, "two frontier goals and the area seen", within_s=60)
    assert explored["state"] == "exploring", explored
    brief = status(daemon)["navigation"]
    assert brief["exploration"]["state"] == "exploring" and brief["state"] != "idle", brief
    code, body = daemon.post("/api/autonomy", {"mode": "off"})
    assert code == 200 and body["mode"] == "off", body
    assert body["exploration"]["state"] == "canceled", body
    assert daemon.get("/api/goal")[1]["state"] == "canceled"
    assert "exploring (requested over HTTP)" in daemon.log()


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "daemon.cli", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONUNBUFFERED": "1"})


def test_a_mission_file_with_a_bad_step_is_refused_naming_the_step_and_field(
        tmp_path: Path) -> None:
    bad = tmp_path / "tour.toml"
    bad.write_text('name = "tour"\n[[steps]]\nx = 1.0\ny = 0.0\n[[steps]]\nx = "far"\n'
                   'y = 0.0\n')
    nobody = "--url", "127.0.0.1:9"  # nothing is sent: the file is checked first
    result = run_cli("mission", str(bad), *nobody)
    assert result.returncode == 1
    assert f"{bad}: steps[1].x: expected a finite number" in result.stderr, result.stderr
    as_json = tmp_path / "tour.json"
    as_json.write_text(json.dumps({"steps": [{"x": 1.0, "y": 0.0}, {"x": 1.0, "y": 0.0,
                                                                    "speed": 2}]}))
    result = run_cli("mission", str(as_json), *nobody)
    assert result.returncode == 1 and "steps[1].speed: unknown field" in result.stderr
    broken = tmp_path / "broken.toml"
    broken.write_text("[[steps]\nx = 1\n")
    result = run_cli("mission", str(broken), *nobody)
    assert result.returncode == 1 and "not valid TOML" in result.stderr, result.stderr
    good = tmp_path / "good.toml"
    good.write_text("[[steps]]\nx = 1\ny = 0\n")
    result = run_cli("mission", str(good), *nobody)
    assert result.returncode == 69 and "cannot reach" in result.stderr, result.stderr


def test_a_mission_file_drives_the_robot_through_its_steps(
        daemon_subprocess: StartDaemonSubprocess, tmp_path: Path) -> None:
    daemon = daemon_subprocess('[sim]\ndriver = "mock"\nworld_file = "apartment"\n'
                               '[security]\ntoken = "m1ssion-t0ken"\n', args=("--sim",))
    wait_for(lambda: status(daemon)["safety"]["zone"] != "unknown", "the first revolution")
    first = between(START, (-0.5, -2.5, 0.0))  # 0.5 m ahead
    x, y, yaw = between(START, GOAL)
    mission = tmp_path / "living-room.toml"
    mission.write_text(f'name = "living room"\n[[steps]]\nx = {first[0]}\ny = {first[1]}\n'
                       f'frame = "odom"\n[[steps]]\nx = {x}\ny = {y}\ntheta = {yaw}\n'
                       'frame = "odom"\n')
    result = run_cli("mission", str(mission), "--config", str(daemon.config_path))
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == "mission 'living room': 2 steps started", lines
    assert lines[1].startswith("step 1/2 succeeded in "), lines
    assert lines[2].startswith("step 2/2 succeeded in "), lines
    assert lines[3] == "mission 'living room' succeeded", lines
    wait_for(lambda: abs(status(daemon)["ground_truth"]["v"]) < 0.01, "the robot at rest")
    truth = status(daemon)["ground_truth"]
    assert math.hypot(truth["x"] - GOAL[0], truth["y"] - GOAL[1]) <= 0.10, truth
    assert daemon.get("/api/sim/metrics")[1]["collisions"] == 0
