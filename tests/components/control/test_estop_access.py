# Anyone who may reach the robot may stop it: latching the e-stop needs no token, releasing it
# does; latches are limited per peer (never one that stops the robot) and logged with who.
from __future__ import annotations

import logging
import re
from pathlib import Path

import aiohttp
import pytest

from daemon.components.control.estop import LatchLimit, estop_access
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rosbridge import OWNER, TWIST, WITH_TOKEN, connect
from tests.support.wait import eventually


async def post_estop(robot: InProcessDaemon, engaged: bool, headers: dict[str, str] | None = None
                     ) -> tuple[int, dict[str, object], dict[str, str]]:
    async with aiohttp.ClientSession() as session, session.post(
            robot.http_url + "/api/estop", json={"engaged": engaged, "reason": "test"},
            headers=headers or {}) as response:
        return response.status, await response.json(), dict(response.headers)


def test_one_rule_for_both_directions() -> None:
    assert estop_access(True) == "stop" and estop_access(False) == "drive"


async def test_http_latch_needs_no_token_and_release_does(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, "arbiterd")
    async with in_process_daemon(tmp_path, WITH_TOKEN) as robot:
        control = robot.control
        status, body, _ = await post_estop(robot, True)
        assert (status, body) == (200, {"engaged": True})
        assert control.arbiter.estop_engaged
        assert "e-stop engaged by HTTP 127.0.0.1: test" in caplog.text
        status, body, headers = await post_estop(robot, False)
        assert status == 401 and "token" in str(body["error"])
        assert headers["WWW-Authenticate"].startswith("Bearer")
        assert await post_estop(robot, False, {"Authorization": "Bearer wrong"}) != 200
        assert control.arbiter.estop_engaged
        status, body, _ = await post_estop(robot, False, OWNER)
        assert (status, body) == (200, {"engaged": False})
        assert "e-stop released by HTTP 127.0.0.1" in caplog.text


async def test_http_latch_from_a_foreign_page_is_refused(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, WITH_TOKEN) as robot:
        status, body, _ = await post_estop(robot, True, {"Origin": "http://evil.example"})
        assert status == 403 and "may not stop this robot" in str(body["error"])
        status, _, _ = await post_estop(robot, True, {"Origin": "http://127.0.0.1:8085"})
        assert status == 200
        assert robot.control.arbiter.estop_engaged


async def test_repeated_latches_are_limited_but_a_stop_never_is(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, "arbiterd.control")
    async with in_process_daemon(tmp_path, WITH_TOKEN) as robot:
        limit = robot.component("control").latches
        limit.window_s = 60.0  # the whole test is one window: no race with the clock
        answers = [(await post_estop(robot, True))[0] for _ in range(limit.burst + 3)]
        assert answers == [200] * limit.burst + [429] * 3
        status, body, headers = await post_estop(robot, True)
        assert status == 429 and "already engaged" in str(body["error"])
        assert headers["Retry-After"] == "1"
        assert caplog.text.count("e-stop engaged by") == limit.burst  # refusals cost no line
        # released by the token holder: the same peer, over its limit, still stops the robot
        assert (await post_estop(robot, False, OWNER))[0] == 200
        assert (await post_estop(robot, True))[0] == 200
        assert robot.control.arbiter.estop_engaged


async def test_rosbridge_latch_needs_no_token_and_release_does(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, "arbiterd")
    async with in_process_daemon(tmp_path, WITH_TOKEN) as robot:
        control = robot.control
        async with connect(robot.ws_url) as anonymous:
            await anonymous.send(op="advertise", topic="/estop", type="std_msgs/msg/Bool",
                                 id="adv")
            await anonymous.send(op="publish", topic="/estop", msg={"data": True}, id="latch")
            await eventually(lambda: control.arbiter.estop_engaged, "the tokenless latch")
            await anonymous.send(op="publish", topic="/estop", msg={"data": False}, id="rel")
            refusal = await anonymous.op("status", id="rel")
            assert "publish /estop: needs a valid token" in refusal["msg"]
            assert [m for m in anonymous.received if m.get("op") == "status"] == [refusal]
            await anonymous.send(op="publish", topic="/cmd_vel", msg=TWIST, id="drive")
            assert "needs a valid token" in (await anonymous.op("status", id="drive"))["msg"]
        assert control.arbiter.estop_engaged and not robot.moving()
        assert re.search(r"e-stop engaged by rosbridge client \d+ \(127\.0\.0\.1\)",
                         caplog.text), caplog.text
        async with connect(robot.ws_url, headers=OWNER) as owner:
            await owner.send(op="publish", topic="/estop", msg={"data": False})
            await eventually(lambda: not control.arbiter.estop_engaged, "the release")


def test_the_latch_limit_is_per_peer_windowed_and_bounded() -> None:
    now = [0.0]
    limit = LatchLimit(burst=2, window_s=1.0, peers=3, clock=lambda: now[0])
    assert [limit.allow("a") for _ in range(3)] == [True, True, False]
    assert limit.allow("b") and limit.limited == 1  # another peer has its own budget
    now[0] = 1.0
    assert limit.allow("a")  # a new window
    for i in range(1000):  # many peers: memory stays at the bound
        limit.allow(f"10.0.{i // 256}.{i % 256}")
    assert len(limit) == 3
    assert limit.allow("a") and limit.allow("a")  # forgotten: a fresh budget, never less
