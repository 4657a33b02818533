# One validator for every coordinate and pose that comes in: huge, non-finite or missing is a 4xx.
from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from daemon import coords
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rosbridge import connect
from tests.support.topic_samples import everything

HUGE = (1e16, 1e308, -1e308, 10**30)


@pytest.fixture
async def robot(tmp_path: Path) -> AsyncIterator[InProcessDaemon]:
    async with in_process_daemon(tmp_path, everything(tmp_path)) as robot:
        yield robot


def test_the_validator_names_the_field() -> None:
    for value in (*HUGE, 10**400, float("nan"), float("inf"), None, "1", True):
        with pytest.raises(coords.CoordinateError, match=r"^waypoints\[2\]\[0\]: "):
            coords.coordinate(value, "waypoints[2][0]")
    assert coords.coordinate(-12.5, "x") == -12.5
    with pytest.raises(coords.CoordinateError, match="outside the map"):
        coords.point([30.0, 0.0], ("x", "y"), coords.Extent(0.0, 0.0, 20.0, 20.0))
    assert coords.missing_required({"pose": {"orientation": {}}}, ("pose.position.x",)) == \
        "pose.position: missing (required)"


def bodies(value: Any) -> list[tuple[str, dict[str, Any], str]]:
    """(route, body, the field the answer must name) for every HTTP entry point of a pose."""
    return [("/api/pose", {"x": value, "y": 0.0}, "x"),
            ("/api/goal", {"x": 0.5, "y": value}, "y"),
            ("/api/goal", {"waypoints": [[0.5, 0.5], [value, 0.0]]}, "waypoints[1][0]"),
            ("/api/mission", {"steps": [{"x": 0.5, "y": 0.5}, {"x": value, "y": 0}]},
             "steps[1].x"),
            ("/api/fetch", {"object": [value, 0.0], "drop": [0.0, 0.0]}, "object[0]"),
            ("/api/map/load", {"name": "none", "pose": {"x": value, "y": 0}}, "")]


@pytest.mark.parametrize("value", HUGE)
async def test_huge_coordinates_are_refused_on_every_http_entry(
        robot: InProcessDaemon, value: float) -> None:
    """Before: POST /api/pose with x >= 1e16 was accepted and killed the mapper; 1e308 in a
    goal, waypoint, mission or fetch answered 500 with a traceback."""
    refused = []
    async with aiohttp.ClientSession() as http:
        for route, body, field in bodies(value):
            raw = str(body).replace("'", '"').replace("inf", "1e999")
            async with http.post(robot.http_url + route, data=raw,
                                 headers={"Content-Type": "application/json"}) as answer:
                text = await answer.text()
                assert 400 <= answer.status < 500, (route, answer.status, text)
                assert field in text and "Traceback" not in text, (route, text)
                refused.append(answer.status)
    print(f"{value:g}: {len(refused)} entry points refused with {sorted(set(refused))}")
    assert not robot.moving()
    assert robot.component("mapping").runner is not None  # the mapper lives on


async def test_a_goal_pose_without_a_position_is_refused(robot: InProcessDaemon) -> None:
    """Before: a /goal_pose without a position became a goal to (0, 0)."""
    navigation = robot.component("navigation")
    goals = navigation.navigator.goals
    async with connect(robot.ws_url) as client:
        for msg, field in (({"header": {"frame_id": "map"}, "pose": {"orientation": {}}},
                            "msg.pose.position: missing"),
                           ({"pose": {"position": {"x": 1e16, "y": 0.0}}},
                            "pose.position.x: 1e+16 m is beyond")):
            await client.send(op="publish", topic="/goal_pose", msg=msg,
                              type="geometry_msgs/msg/PoseStamped")
            await client.expect(lambda m, f=field: f in str(m.get("msg", "")),
                                what=f"a refusal naming {field}")
        await client.send(op="publish", topic="/initialpose",
                          type="geometry_msgs/msg/PoseWithCovarianceStamped",
                          msg={"header": {"frame_id": "map"},
                               "pose": {"pose": {"position": {"x": 1e308, "y": 0.0}}}})
        await client.expect(lambda m: "pose.pose.position.x" in str(m.get("msg", "")),
                            what="the /initialpose refusal")
    assert navigation.navigator.goals == goals and not robot.moving()
    assert robot.component("mapping").runner is not None
