# The navigation component in lockstep simulated time against the true world: goals reached,
# unreachable ones failed in bounded time, teleop, e-stop and stale scans, and bad goals refused.
from __future__ import annotations

import json
import math
from collections.abc import AsyncIterator

import pytest

from daemon.config import load_config
from daemon.control.commands import Twist
from daemon.lockstep.runner import Lockstep
from daemon.navigation.component import NavigationComponent
from daemon.navigation.messages import GoalError, GoalRequest, goal_of_pose_stamped
from slam.pose import Pose2, between

APARTMENT_START: Pose2 = (-1.0, -2.5, 0.0)


@pytest.fixture
async def apartment() -> AsyncIterator[Lockstep]:
    config = load_config(None, sim=True, env={})
    config.update("sim", {"world_file": "apartment", "seed": 3})
    lockstep = Lockstep(config, navigation=True)
    await lockstep.begin()
    await lockstep.advance(0.3)
    yield lockstep
    await lockstep.finish()


def nav_of(lockstep: Lockstep) -> NavigationComponent:
    assert lockstep.navigation is not None
    return lockstep.navigation


async def go(lockstep: Lockstep, world_goal: Pose2, seconds: float = 60.0) -> float:
    """Send a goal given in the world's frame; run until it ends; the simulated seconds."""
    nav = nav_of(lockstep)
    x, y, theta = between(APARTMENT_START, world_goal)
    nav.request(GoalRequest("odom", x, y, theta))
    began = lockstep.now
    await lockstep.advance(seconds, until=lambda: not nav.navigator.active)
    return lockstep.now - began


async def test_a_goal_through_a_doorway_is_reached_by_ground_truth(
        apartment: Lockstep) -> None:
    goal = (-0.2, 2.4, math.pi / 2)  # the bathroom, through its door
    await go(apartment, goal)
    await apartment.advance(0.5)
    nav, truth = nav_of(apartment), apartment.world.physics.state
    assert nav.navigator.state == "succeeded", nav.status()
    assert math.hypot(truth.x - goal[0], truth.y - goal[1]) <= 0.10
    assert abs(math.remainder(truth.theta - goal[2], math.tau)) <= 0.1
    assert apartment.world.metrics_summary()["collisions"] == 0
    status = nav.status()
    assert status["replans"] >= 1 and status["distance_remaining_m"] < 0.1


async def test_a_goal_inside_the_table_fails_with_its_reason_within_60_s(
        apartment: Lockstep) -> None:
    seconds = await go(apartment, (-2.5, -1.3, 0.0), seconds=70.0)  # the table
    nav = nav_of(apartment)
    assert nav.navigator.state == "failed", nav.status()
    assert nav.navigator.reason
    assert seconds < 60.0
    assert not nav.navigator.active and "navigation" not in apartment.control.arbiter.sources


async def test_teleop_cancels_the_goal_and_the_e_stop_fails_it(apartment: Lockstep) -> None:
    nav = nav_of(apartment)
    nav.request(GoalRequest("odom", 1.5, 1.0, None))
    await apartment.advance(2.0)
    assert nav.navigator.state == "following"
    await apartment.control.submit("teleop", Twist(0.0, 0.0), t_recv=apartment.now)
    assert nav.navigator.state == "canceled" and "teleop" in nav.navigator.reason
    apartment.control.arbiter.drop("teleop")

    nav.request(GoalRequest("odom", 1.5, 1.0, None))
    await apartment.advance(2.0)
    await apartment.control.engage_estop("test")
    await apartment.advance(0.2)
    assert nav.navigator.state == "failed" and "e-stop" in nav.navigator.reason
    with pytest.raises(GoalError, match="e-stop engaged"):
        nav.request(GoalRequest("odom", 1.0, 0.0, None))
    apartment.control.release_estop()
    await apartment.advance(1.0)
    assert apartment.world.physics.state.v == pytest.approx(0.0, abs=1e-3)


async def test_a_stale_scan_holds_the_robot_then_fails_the_goal(apartment: Lockstep) -> None:
    nav = nav_of(apartment)
    nav.request(GoalRequest("odom", 1.5, 1.0, None))
    await apartment.advance(2.0)
    apartment.lidar.stalled = True
    await apartment.advance(1.5)
    assert nav.navigator.active and abs(apartment.world.physics.state.v) < 0.01
    await apartment.advance(5.0)
    assert nav.navigator.state == "failed" and "no fresh lidar scan" in nav.navigator.reason


async def test_bad_goals_are_refused_with_the_reason_and_a_new_goal_replaces_the_old(
        apartment: Lockstep) -> None:
    nav = nav_of(apartment)
    nan = {"header": {"frame_id": "odom"},
           "pose": {"position": {"x": math.nan, "y": 0.0}, "orientation": {"w": 1.0}}}
    with pytest.raises(GoalError, match=r"pose\.position\.x: expected a finite number"):
        goal_of_pose_stamped(nan)
    with pytest.raises(GoalError, match="frame_id is 'base_link'"):
        nav.request(GoalRequest("base_link", 1.0, 0.0, None))
    with pytest.raises(GoalError, match=r"needs \[mapping\] enabled"):
        nav.request(GoalRequest("map", 1.0, 0.0, None))
    with pytest.raises(GoalError, match="outside the map"):
        nav.request(GoalRequest("odom", 100.0, 0.0, None))
    nav.request(GoalRequest("odom", 1.0, 0.0, None))  # a first plan: the costmap is filled
    await apartment.advance(0.5)
    wall = between(APARTMENT_START, (1.0, -3.0, 0.0))  # the kitchen wall, seen from the start
    with pytest.raises(GoalError, match="inside an obstacle"):
        nav.request(GoalRequest("odom", wall[0], wall[1], None))
    assert nav.navigator.goals == 1 and nav.navigator.active  # a refusal changes nothing
    nav.request(GoalRequest("odom", 1.5, 0.5, None))
    assert nav.navigator.goals == 2 and nav.navigator.target is not None
    assert nav.navigator.target.x == 1.5


def test_simulate_goals_prints_each_goal_judged_by_ground_truth(
        capsys: pytest.CaptureFixture[str]) -> None:
    from daemon.cli import main

    assert main(["simulate", "--goals", "1", "--world", "apartment", "--seed", "2",
                 "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    (goal,) = report["goals"]
    assert goal["reachable"] and goal["reached"] and goal["state"] == "succeeded"
    assert goal["error_m"] <= 0.10 and goal["ratio"] is not None
    assert report["summary"]["all"]["collisions"] == 0
    assert main(["simulate", "--goals", "0", "--world", "apartment"]) == 2
