# The navigation component in lockstep simulated time against the true world: goals reached,
# unreachable ones failed in bounded time, teleop, e-stop and stale scans, and bad goals refused.
from __future__ import annotations

import json
import math
import re
from collections.abc import AsyncIterator

import pytest

from daemon.commands import Twist
from daemon.components.navigation.messages import GoalError, GoalRequest, goal_of_pose_stamped
from daemon.components.navigation.mission import mission_of_json
from daemon.lockstep.runner import Lockstep
from slam.pose import Pose2, between
from tests.support.navigation import apartment_lockstep, nav_of

APARTMENT_START: Pose2 = (-1.0, -2.5, 0.0)


@pytest.fixture
async def apartment() -> AsyncIterator[Lockstep]:
    async with apartment_lockstep() as lockstep:
        yield lockstep


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


async def test_an_unseen_goal_fails_only_once_the_robot_comes_no_nearer(
        apartment: Lockstep) -> None:
    # a goal down a long aisle stays unseen while the robot drives to it (the rays along the
    # aisle have no return): the "never seen" rule waits until it stops getting nearer
    nav = nav_of(apartment)
    nav.request(GoalRequest("odom", 4.0, 0.0, None))
    row, col = nav.area.cell(4.0, 0.0)
    here = [(0.0, 0.0, 0.0)]
    nav._here = lambda: here[0]  # type: ignore[method-assign]
    steps = 0
    while here[0][0] < 3.6:  # 0.3 m/s for 12 s, then held 0.4 m short
        nav.costmap.seen[row, col] = False
        assert nav._never_seen() is None
        here[0] = (min(here[0][0] + 0.3 * nav.period, 3.6), 0.0, 0.0)
        steps += 1
    held = 0
    while (reason := nav._never_seen()) is None:
        held += 1
        assert held * nav.period < 2.0 + 1.0
    assert "came no nearer" in reason and held * nav.period >= 1.5


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


def odom_goal(world_goal: Pose2) -> dict[str, float | str]:
    x, y, theta = between(APARTMENT_START, world_goal)
    return {"x": x, "y": y, "theta": theta, "frame": "odom"}


async def test_a_mission_runs_its_steps_in_turn_with_a_result_each(apartment: Lockstep) -> None:
    nav = nav_of(apartment)
    living, bathroom = (0.0, -0.5, math.pi / 2), (-0.2, 2.4, math.pi / 2)
    nav.start_mission(mission_of_json({"name": "tour", "steps": [
        odom_goal(living), odom_goal(bathroom), odom_goal((-2.5, -1.3, 0.0))]}, "odom"))
    mission = nav.mission
    assert mission is not None
    await apartment.advance(180.0, until=lambda: mission.index == 2 or not mission.running)
    truth = apartment.world.physics.state  # where step 2 ended: the bathroom
    assert math.hypot(truth.x - bathroom[0], truth.y - bathroom[1]) <= 0.10, truth
    await apartment.advance(90.0, until=lambda: not mission.running)
    report = nav.status()["mission"]
    assert report["name"] == "tour" and report["state"] == "failed", report
    states = [r["state"] for r in report["results"]]
    assert states == ["succeeded", "succeeded", "failed"], report
    assert report["reason"].startswith("step 3: ") and report["results"][2]["reason"], report
    assert all(r["elapsed_s"] > 0 for r in report["results"][:2]), report
    assert apartment.world.metrics_summary()["collisions"] == 0


async def test_a_mission_ends_canceled_by_a_goal_or_teleop_and_bad_steps_are_named(
        apartment: Lockstep) -> None:
    nav = nav_of(apartment)
    for body, problem in (({"steps": []}, "steps: expected a list of 1..100 goals"),
                          ({"steps": [{"x": 1.0, "y": 0.0}, {"x": "far"}]},
                           "steps[1].x: expected a finite number"),
                          ({"steps": [{"x": 1.0, "y": 0.0}], "loop": True},
                           "loop: unknown field")):
        with pytest.raises(GoalError, match=re.escape(problem)):
            mission_of_json(body, "odom")
    with pytest.raises(GoalError, match=r"step 1: .*outside the map"):
        nav.start_mission(mission_of_json({"steps": [{"x": 500.0, "y": 0.0}]}, "odom"))
    assert nav.mission is None
    nav.start_mission(mission_of_json({"steps": [odom_goal((0.0, -0.5, 0.0))] * 2}, "odom"))
    await apartment.advance(1.0)
    nav.request(GoalRequest("odom", 0.5, 0.0, None))  # a goal replaces the mission
    assert nav.status()["mission"]["state"] == "canceled"
    assert [r["state"] for r in nav.status()["mission"]["results"]] == ["canceled", "skipped"]
    nav.start_mission(mission_of_json({"steps": [odom_goal((0.0, -0.5, 0.0))]}, "odom"))
    await apartment.advance(1.0)
    await apartment.control.submit("http", Twist(0.0, 0.0), t_recv=apartment.now)  # teleop wins
    await apartment.advance(0.2)
    report = nav.status()["mission"]
    assert report["state"] == "canceled" and "teleop" in report["reason"], report
