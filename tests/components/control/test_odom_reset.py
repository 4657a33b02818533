# Odometry reset (POST /api/odom/reset) and the simulator's reset putting odometry on the robot.
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from daemon.components.control.kinematics import DiffDrive
from daemon.components.control.odometry import Odometry, Pose2D
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.wait import eventually


async def call(robot: InProcessDaemon, method: str, path: str, body: Any = None) -> tuple[int, Any]:
    async with aiohttp.ClientSession() as session, session.request(
            method, robot.http_url + path, json=body) as response:
        return response.status, await response.json()


async def drive_off(robot: InProcessDaemon) -> dict[str, Any]:
    """Drive a little forward and turning; the status once odometry is away from the start."""
    control = robot.control

    async def away() -> dict[str, Any] | None:
        assert (await call(robot, "POST", "/api/cmd_vel",
                           {"linear": {"x": 0.3}, "angular": {"z": 0.6}}))[0] == 200
        status = control.status()
        return status if math.hypot(status["pose"]["x"], status["pose"]["y"]) > 0.1 else None

    status: dict[str, Any] = await eventually(away, "odometry to leave the start")
    await call(robot, "POST", "/api/cmd_vel", {})
    return status


def test_a_reset_moves_the_reported_frame_only() -> None:
    odometry = Odometry(DiffDrive(0.3, 0.05))
    odometry.update_open_loop(1.0, 0.5, 1.0)  # away and turned
    inside = odometry.pose
    odometry.reset(Pose2D(2.0, -1.0, math.pi / 2))
    assert odometry.pose == inside  # what the collision monitor and wander see: no jump
    assert odometry.reported == pytest.approx(Pose2D(2.0, -1.0, math.pi / 2))
    odometry.update_open_loop(1.0, 0.0, 1.0)  # 1 m straight ahead
    reported = odometry.reported
    assert (reported.x, reported.y, reported.theta) == pytest.approx(
        (2.0, 0.0, math.pi / 2), abs=1e-9)  # ahead is +y in the reset frame


async def test_odometry_reset_over_http(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path) as robot:
        await drive_off(robot)
        control = robot.control
        status, body = await call(robot, "POST", "/api/odom/reset", {})
        assert status == 200 and body["pose"]["x"] == body["pose"]["y"] == 0.0, body
        inside = control.odometry.pose  # what the collision monitor sees did not jump
        assert math.hypot(inside.x, inside.y) > 0.1
        pose = control.status()["pose"]
        assert math.hypot(pose["x"], pose["y"]) < 0.05 and abs(pose["theta"]) < 0.05
        status, body = await call(robot, "POST", "/api/odom/reset", {"x": 1, "theta": 1.5})
        assert status == 200 and body["pose"]["x"] == pytest.approx(1.0, abs=0.05)
        for bad, message in (({"z": 1}, "invalid pose: z: unknown field"),
                             ({"x": "far"}, "invalid pose: x: expected a finite number")):
            status, body = await call(robot, "POST", "/api/odom/reset", bad)
            assert status == 422 and message in body["error"], body


async def test_a_simulator_reset_puts_odometry_on_the_ground_truth(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path) as robot:
        await drive_off(robot)
        status, body = await call(robot, "POST", "/api/sim/reset", {"x": 0.5, "y": -0.5,
                                                                    "theta": 1.0})
        assert status == 200, body
        truth = body["ground_truth"]
        pose = robot.control.status()["pose"]
        assert (pose["x"], pose["y"], pose["theta"]) == pytest.approx(
            (truth["x"], truth["y"], truth["theta"]), abs=0.02)
        obstacle = robot.ctx.sim.world.world.circles[0]
        status, body = await call(robot, "POST", "/api/sim/reset", {"x": obstacle.x,
                                                                    "y": obstacle.y})
        assert status == 400 and "cannot place the robot there" in body["error"], body
        status, body = await call(robot, "POST", "/api/sim/reset", {"x": True})
        assert status == 422 and "invalid pose: x" in body["error"], body


async def test_the_recorder_reports_its_file_and_size(tmp_path: Path) -> None:
    config = f'[recorder]\ndirectory = "{tmp_path / "rec"}"\nflush_interval_s = 0.1\n'
    async with in_process_daemon(tmp_path, config) as robot:
        status, body = await call(robot, "POST", "/api/record", {"enabled": True})
        assert status == 200 and body["recording"] is True, body
        recorder = robot.component("recorder")
        health = await eventually(lambda: (h := recorder.health().to_json())["file_bytes"] and h,
                                  "the file to grow")
        assert health["file"].endswith(".mcap") and health["file_bytes"] > 0
        status, body = await call(robot, "POST", "/api/record", {"enabled": False})
        assert status == 200 and body["file_bytes"] is None and body["file"] is None
