# The dock over HTTP and rosbridge's /dock/command: setting it, refusals, bad input.
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from tests.support.in_process_daemon import in_process_daemon

TOKEN = "d0ck-t0ken-l0ng"


def dock_toml(tmp_path: Path, navigation: bool = True) -> str:
    return (f'[security]\ntoken = "{TOKEN}"\n[navigation]\nenabled = {str(navigation).lower()}\n'
            f'[dock]\nfile = "{tmp_path / "dock.json"}"\n')


async def post(http: aiohttp.ClientSession, url: str, body: Any,
               token: str | None = TOKEN) -> tuple[int, dict[str, Any]]:
    headers = {"Content-Type": "application/json"}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    data = body if isinstance(body, str) else json.dumps(body)
    async with http.post(url, data=data, headers=headers) as answer:
        return answer.status, await answer.json()


async def test_set_the_dock_go_home_and_leave_refusals(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, dock_toml(tmp_path)) as robot, \
            aiohttp.ClientSession() as http:
        url = f"{robot.http_url}/api/dock"
        async with http.get(url) as answer:
            state = await answer.json()
        assert state["dock"] is None and state["state"] == "IDLE"
        status, body = await post(http, f"{url}/go", {})
        assert status == 409 and "no dock known" in body["error"]
        status, body = await post(http, f"{url}/leave", {})
        assert status == 409 and "not on the dock" in body["error"]
        status, body = await post(http, url, {"x": 1.5, "y": -0.5, "theta": 3.0})
        assert status == 200 and body["dock"] == {"frame": "odom", "x": 1.5, "y": -0.5,
                                                  "theta": 3.0}
        saved = json.loads((tmp_path / "dock.json").read_text())
        assert saved["x"] == 1.5 and saved["frame"] == "odom"
        status, body = await post(http, url, {"here": True})
        assert status == 200 and abs(body["dock"]["x"]) < 0.05  # the robot has not moved
        status, body = await post(http, url, {"x": 1.0, "y": 0.0, "theta": 0.0,
                                              "frame": "map"})
        assert status == 409 and "map" in body["error"]
    # kept across restarts
    async with in_process_daemon(tmp_path, dock_toml(tmp_path)) as robot:
        assert robot.component("dock").dock[0] == "odom"


@pytest.mark.parametrize(("body", "field"), [
    ({"x": 1.0, "y": 0.0}, "theta: missing"),
    ({"x": "1", "y": 0.0, "theta": 0.0}, "x: expected a finite number"),
    ({"x": True, "y": 0.0, "theta": 0.0}, "x: expected a finite number"),
    ({"x": 1e308, "y": 0.0, "theta": 0.0}, "x: expected a finite number"),
    ('{"x": NaN, "y": 0, "theta": 0}', "NaN"),
    ({"x": 1.0, "y": 0.0, "theta": 0.0, "speed": 3}, "speed: unknown field"),
    ({"here": 1}, "here: expected true"),
    ({"here": True, "x": 1.0}, "here: expected true, alone"),
    ({"x": 1.0, "y": 0.0, "theta": 0.0, "frame": ["odom"]}, "frame: expected a frame name"),
    ("[1, 2]", ""),
    ("{" * 2000, ""),
])
async def test_bad_dock_poses_are_refused_naming_the_field(tmp_path: Path, body: Any,
                                                            field: str) -> None:
    async with in_process_daemon(tmp_path, dock_toml(tmp_path)) as robot, \
            aiohttp.ClientSession() as http:
        status, answer = await post(http, f"{robot.http_url}/api/dock", body)
        assert status in (400, 413, 422), answer
        assert field in answer["error"] + str(answer.get("detail", ""))
        assert robot.component("dock").dock is None


async def test_without_the_token_nothing_moves(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, dock_toml(tmp_path)) as robot, \
            aiohttp.ClientSession() as http:
        for path in ("", "/go", "/leave"):
            status, _ = await post(http, f"{robot.http_url}/api/dock{path}",
                                   {"x": 0.0, "y": 0.0, "theta": 0.0} if not path else {},
                                   token=None)
            assert status == 401
        assert robot.component("dock").dock is None


async def test_without_navigation_going_home_is_refused_saying_why(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, dock_toml(tmp_path, navigation=False)) as robot, \
            aiohttp.ClientSession() as http:
        status, body = await post(http, f"{robot.http_url}/api/dock/go", {})
        assert status == 409 and "[navigation]" in body["error"]
        status, body = await post(http, f"{robot.http_url}/api/dock", {"here": True})
        assert status == 409 and "navigation" in body["error"]


async def test_the_rosbridge_command_is_checked(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, dock_toml(tmp_path)) as robot:
        dock = robot.component("dock")
        refusal = await dock.on_command_message(_message("dance"))
        assert refusal is not None and "expected go or leave" in refusal.reason
        refusal = await dock.on_command_message(_message("go"))
        assert refusal is not None and "no dock known" in refusal.reason
        dock.set_dock("odom", (2.0, 0.0, 0.0))
        assert await dock.on_command_message(_message("go")) is None
        assert dock.state == "NAVIGATING" and math.isclose(
            robot.component("navigation").navigator.target.x, 2.0 - 0.6)
        dock.cancel("test")


def _message(data: str) -> Any:
    from daemon.topics import Inbound
    return Inbound("/dock/command", "std_msgs/msg/String", {"data": data}, "ws:1", "test", 0.0,
                   "127.0.0.1")
