# /odom_ground_truth is the true pose in the odometry frame: beside /odom at the start, through
# a drive and after an odometry reset, whatever the world's start pose (issue 40 item 3).
from __future__ import annotations

import math
from pathlib import Path

import aiohttp
import pytest

from daemon.telemetry import ODOM, ODOM_GROUND_TRUTH
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.wait import eventually


def gap(robot: InProcessDaemon) -> tuple[float, float]:
    """Distance (m) and heading difference (rad) between the truth and odometry."""
    truth, odom = robot.ctx.bus.latest(ODOM_GROUND_TRUTH), robot.ctx.bus.latest(ODOM)
    assert truth is not None and odom is not None
    turn = math.remainder(truth.theta - odom.theta, math.tau)
    return math.hypot(truth.x - odom.x, truth.y - odom.y), abs(turn)


async def post(robot: InProcessDaemon, path: str, body: dict[str, object]) -> None:
    async with aiohttp.ClientSession() as session, \
            session.post(robot.http_url + path, json=body) as answer:
        assert answer.status == 200, await answer.text()


async def test_the_truth_is_drawn_where_odometry_is(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    # the warehouse starts the robot at (7, 0) facing -x: the world's frame is not odometry's
    monkeypatch.setenv("ARBITERD_SIM_WORLD_FILE", "warehouse")
    async with in_process_daemon(tmp_path) as robot:
        await eventually(lambda: robot.ctx.bus.latest(ODOM_GROUND_TRUTH) is not None,
                         "the first ground truth")
        distance, turn = gap(robot)
        assert distance < 0.05 and turn < 0.05, (distance, turn)

        for _ in range(10):  # forward: odometry's +x, wherever the world points
            await post(robot, "/api/cmd_vel", {"linear": {"x": 0.3}})
            await eventually(lambda: robot.ctx.bus.latest(ODOM).x > 0.0, "odometry moving")
        truth = await eventually(
            lambda: (t := robot.ctx.bus.latest(ODOM_GROUND_TRUTH)) and t.x > 0.02 and t,
            "the truth moving the same way")
        assert abs(truth.y) < 0.05, truth

        await post(robot, "/api/odom/reset", {"x": 1.0, "y": 2.0, "theta": 0.5})
        await eventually(lambda: gap(robot)[0] < 0.05 and gap(robot)[1] < 0.05,
                         "the truth moved with the odometry reset")
