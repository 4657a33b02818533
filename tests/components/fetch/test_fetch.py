# The fetch mission: in lockstep (the warehouse, ground truth) a fetch delivers the object; the
# e-stop, a cancel and a missed grasp end it safe with the reason; bad requests are refused.
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import aiohttp
import numpy as np
import pytest

from daemon.commands import Twist
from daemon.components.fetch.component import STATE, FetchComponent
from daemon.components.fetch.sequence import FetchError
from daemon.lockstep.fetch import FetchRun
from daemon.lockstep.runner import Lockstep
from sim.objects import Objects, Tool, cast_circles
from tests.support.in_process_daemon import in_process_daemon
from tests.support.rosbridge import connect
from tests.support.wait import eventually

#: in the warehouse's loading area, near the start (7, 0) facing -x
OBJECT, DROP = (5.0, 1.5), (5.5, -2.5)
WALL = (4.5, 0.5)  # on the wall of a shelf row's end


class Fetching:
    """A lockstep warehouse with the arm and the fetch; the states /fetch/state carried."""

    def __init__(self) -> None:
        self.run = FetchRun("warehouse", 1, 0)
        self.lockstep: Lockstep = self.run.lockstep
        fetch = self.lockstep.fetch
        assert fetch is not None and fetch.sequence is not None
        self.fetch: FetchComponent = fetch
        self.states: list[str] = []
        self.lockstep.bus.subscribe(STATE, self._on_state)

    def _on_state(self, status: dict[str, Any]) -> None:
        if not self.states or self.states[-1] != status["state"]:
            self.states.append(status["state"])

    async def begin(self) -> None:
        await self.lockstep.begin()
        await self.lockstep.advance(0.5)

    async def until(self, state: str, cap_s: float = 120.0) -> None:
        sequence = self.fetch.sequence
        assert sequence is not None
        await self.lockstep.advance(cap_s, until=lambda: sequence.state == state
                                    or not sequence.active)
        assert sequence.state == state, (sequence.state, sequence.result, sequence.reason)

    def request(self, obj: tuple[float, float], drop: tuple[float, float]) -> None:
        self.fetch.request(self.run._odom(obj), self.run._odom(drop))


async def test_a_fetch_in_lockstep_delivers_the_object_to_the_drop_point() -> None:
    run = FetchRun("warehouse", 1, 0)
    run.pairs = [(OBJECT, DROP)]
    states: list[str] = []
    run.lockstep.bus.subscribe(STATE, lambda s: states.append(s["state"])
                               if not states or states[-1] != s["state"] else None)
    [result] = await run.run()
    assert result["result"] == "succeeded", result["reason"]
    assert result["delivered"] and result["drop_error_m"] <= 0.10 and not result["held"]
    assert result["collisions"] == 0 and result["object_contacts"] == 0
    assert states == ["IDLE", "NAV_TO_OBJECT", "GRASP", "NAV_TO_DROP", "DELIVER", "IDLE"]
    assert list(result["state_times_s"]) == ["NAV_TO_OBJECT", "GRASP", "NAV_TO_DROP",
                                             "DELIVER"]


async def test_the_estop_during_the_grasp_freezes_the_arm_and_ends_the_fetch() -> None:
    f = Fetching()
    await f.begin()
    f.lockstep.world.objects.place(*OBJECT)
    await f.lockstep.advance(0.3)
    f.request(OBJECT, DROP)
    await f.until("GRASP")
    await f.lockstep.advance(0.6)  # into the move to grasp
    arm = f.lockstep.arm
    assert arm is not None and arm.motion.moving(f.lockstep.clock())
    await f.lockstep.control.engage_estop("test")
    await f.lockstep.advance(0.1)
    sequence = f.fetch.sequence
    assert sequence is not None and not sequence.active
    assert sequence.result == "failed"
    assert sequence.reason.startswith("GRASP: e-stop engaged")
    assert "the arm holds where it is (frozen by the e-stop" in sequence.reason
    frozen = arm.motion.position(f.lockstep.clock())
    await f.lockstep.advance(1.0)
    assert arm.motion.position(f.lockstep.clock()) == frozen  # it stays where it froze
    assert not f.fetch.link or f.fetch.link.outcome() is not None  # no goal runs
    assert f.lockstep.world.physics.state.v == pytest.approx(0.0, abs=1e-3)
    assert f.fetch.status()["state"] == "IDLE"
    await f.lockstep.finish()


async def test_the_estop_while_driving_fails_the_fetch_and_navigation() -> None:
    f = Fetching()
    await f.begin()
    f.lockstep.world.objects.place(*OBJECT)
    await f.lockstep.advance(0.3)
    f.request(OBJECT, DROP)
    await f.lockstep.advance(3.0)
    assert f.fetch.sequence is not None and f.fetch.sequence.state == "NAV_TO_OBJECT"
    await f.lockstep.control.engage_estop("test")
    await f.lockstep.advance(0.1)
    sequence = f.fetch.sequence
    assert sequence.result == "failed" and "e-stop engaged" in sequence.reason
    assert f.lockstep.navigation is not None and not f.lockstep.navigation.navigator.active
    await f.lockstep.advance(1.5)
    assert f.lockstep.world.physics.state.v == pytest.approx(0.0, abs=1e-3)
    with pytest.raises(FetchError, match="e-stop engaged"):
        f.request(OBJECT, DROP)
    await f.lockstep.finish()


async def test_cancel_stops_navigation_and_sends_the_arm_home() -> None:
    f = Fetching()
    await f.begin()
    f.request(OBJECT, DROP)
    await f.lockstep.advance(2.0)
    assert f.fetch.cancel("canceled over HTTP")
    sequence = f.fetch.sequence
    assert sequence is not None and sequence.result == "canceled"
    assert "the arm goes to home" in sequence.reason
    assert f.lockstep.navigation is not None and not f.lockstep.navigation.navigator.active
    assert f.states[-1] == "IDLE"
    f.request(OBJECT, DROP)  # a client's command ends it as it ends a goal
    await f.lockstep.advance(1.0)
    await f.lockstep.control.submit("teleop", Twist(0.0, 0.0), t_recv=f.lockstep.now)
    assert sequence.result == "canceled"
    assert sequence.reason.startswith("NAV_TO_OBJECT: teleop from teleop")
    assert f.lockstep.navigation is not None and not f.lockstep.navigation.navigator.active
    await f.lockstep.finish()


async def test_a_grasp_where_no_object_stands_fails_with_the_arm_sent_home() -> None:
    f = Fetching()
    await f.begin()
    f.lockstep.world.objects.place(OBJECT[0] + 0.3, OBJECT[1])  # not where it is said to be
    await f.lockstep.advance(0.3)
    f.request(OBJECT, DROP)
    sequence = f.fetch.sequence
    assert sequence is not None
    await f.lockstep.advance(120.0, until=lambda: not sequence.active)
    assert sequence.result == "failed"
    assert sequence.reason.startswith("GRASP: the object is not held after grasp_close")
    assert "the arm goes to home" in sequence.reason
    await f.lockstep.advance(3.0)
    arm = f.lockstep.arm
    assert arm is not None and arm.pose_at(f.lockstep.clock()) == "home"
    await f.lockstep.finish()


async def test_an_object_inside_a_wall_or_off_the_map_is_refused_naming_why() -> None:
    f = Fetching()
    await f.begin()
    with pytest.raises(FetchError, match=r"object: \(.*\) is inside or against an obstacle"
                       r".*\[fetch\] object_clearance_m"):
        f.request(WALL, DROP)
    with pytest.raises(FetchError, match=r"drop: .* is inside or against an obstacle"):
        f.request(OBJECT, WALL)
    with pytest.raises(FetchError, match=r"object: .* is outside the map"):
        f.request((500.0, 0.0), DROP)
    assert f.fetch.sequence is not None and not f.fetch.sequence.active
    await f.lockstep.finish()


def test_an_object_is_seen_held_only_when_the_fingers_close_on_it_and_put_down() -> None:
    objects = Objects(tolerance=0.04)
    item = objects.place(1.0, 0.0)
    ranges = cast_circles(np.full(4, np.inf), objects.circles(), 0.0, 0.0, 0.0,
                          np.array([0.0, math.pi / 2, math.pi, -math.pi / 2]))
    assert ranges[0] == pytest.approx(1.0 - item.radius) and np.isinf(ranges[1:]).all()
    # the robot at the origin facing +x, the tool point 0.97 m ahead: within the tolerance
    for opening in (0.035, 0.035, 0.03, 0.02, 0.0):
        objects.update(0.0, 0.0, 0.0, Tool(0.97, 0.0, opening), 0.2)
    assert item.held and objects.circles().shape == (0, 3)  # lifted: the lidar misses it
    objects.update(2.0, 1.0, math.pi / 2, Tool(0.5, 0.0, 0.0), 0.2)  # carried
    assert (item.x, item.y) == pytest.approx((2.0, 1.5))
    objects.update(2.0, 1.0, math.pi / 2, Tool(0.5, 0.0, 0.035), 0.2)  # put down
    assert not item.held and (item.x, item.y) == pytest.approx((2.0, 1.5))
    # closing while the arm swings away, or too far from it, holds nothing
    objects.update(2.0, 1.0, math.pi / 2, Tool(0.45, 0.0, 0.02), 0.2)
    assert not item.held
    for opening in (0.035, 0.0):
        objects.update(2.0, 1.0, math.pi / 2, Tool(0.6, 0.0, opening), 0.2)
    assert not item.held and "0.100 m from the object's centre" in objects.miss()


# -- over HTTP -------------------------------------------------------------------------------

async def post(http: aiohttp.ClientSession, url: str, body: bytes | dict[str, Any],
               ) -> tuple[int, Any]:
    data = body if isinstance(body, bytes) else json.dumps(body).encode()
    async with http.post(f"{url}/api/fetch", data=data,
                         headers={"Content-Type": "application/json"}) as answer:
        return answer.status, await answer.json()


async def test_a_fetch_without_the_arm_is_refused_naming_the_section(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path) as robot, aiohttp.ClientSession() as http:
        status, body = await post(http, robot.http_url, {"object": [1, 0], "drop": [0, 1]})
        assert status == 409 and "set [arm] enabled = true" in body["error"]
        async with http.get(f"{robot.http_url}/api/fetch") as answer:
            state = await answer.json()
        assert state == {"state": "IDLE", "available": False,
                         "reason": "the fetch needs the arm: set [arm] enabled = true"}
        assert robot.daemon.health()["components"]["fetch"]["status"] == "ok"


async def test_malformed_fetches_are_refused_naming_the_field(tmp_path: Path) -> None:
    arm = '[arm]\nenabled = true\nbackend = "mock"\n'
    async with in_process_daemon(tmp_path, arm) as robot, aiohttp.ClientSession() as http:
        url = robot.http_url
        for body, code, words in (
                ({"object": [1.0, 0.0]}, 422, "drop: missing"),
                ({"object": [1.0], "drop": [0, 1]}, 422, "object: expected [x, y]"),
                (b'{"object": [1e999, 0.0], "drop": [0, 1]}', 422,
                 "object[0]: expected a finite number"),
                ({"object": [1, 0], "drop": ["a", 1]}, 422, "drop[0]: expected a finite number"),
                ({"object": [1, 0], "drop": [0, 1], "speed": 2}, 422, "speed: unknown field"),
                (b'{"object": [NaN, 0], "drop": [0, 1]}', 400, "not valid JSON"),
                ({"object": [900, 0], "drop": [0, 1]}, 409, "outside the map")):
            status, answer = await post(http, url, body)
            assert status == code and words in answer["error"] + str(answer.get("detail")), \
                (body, status, answer)
        async with http.delete(f"{url}/api/fetch") as answer:
            assert answer.status == 200 and (await answer.json())["state"] == "IDLE"
        async with http.get(f"{url}/api/status") as answer:
            assert (await answer.json())["fetch"]["state"] == "IDLE"
        # an object placed in the simulator, a fetch started, a second refused, a cancel
        async with http.post(f"{url}/api/sim/objects", json={"x": 1.2, "y": "a"}) as answer:
            assert answer.status == 422 and "y: expected a finite number" in \
                (await answer.json())["error"]
        async with http.post(f"{url}/api/sim/objects", json={"x": 1.2, "y": 0.0}) as answer:
            assert answer.status == 200
            assert (await answer.json())["objects"][0]["held"] is False
        status, answer = await post(http, url, {"object": [1.2, 0.0], "drop": [-1.0, 0.0]})
        assert status == 200 and answer["state"] == "NAV_TO_OBJECT", answer
        assert answer["result"] == "running" and answer["held"] is False
        status, answer = await post(http, url, {"object": [1.2, 0.0], "drop": [-1.0, 0.0]})
        assert status == 409 and "a fetch is running (NAV_TO_OBJECT)" in answer["error"]
        async with http.delete(f"{url}/api/fetch") as response:
            answer = await response.json()
        assert answer["state"] == "IDLE" and answer["result"] == "canceled"
        assert answer["reason"] == ("NAV_TO_OBJECT: canceled over HTTP; navigation stopped, "
                                    "the arm goes to home")
        async with http.get(f"{url}/api/goal") as response:
            assert (await response.json())["state"] == "canceled"


async def test_a_fetch_in_run_sim_moves_the_object_through_the_emulated_servos(
        tmp_path: Path) -> None:
    """Real time: the PCA9685 emulator's pulses are what the simulator's gripper does."""
    arm = '[arm]\nenabled = true\nbackend = "pca9685"\n'
    async with in_process_daemon(tmp_path, arm) as robot, aiohttp.ClientSession() as http, \
            connect(robot.ws_url) as client:
        url = robot.http_url
        await client.send(op="subscribe", topic="/fetch/state")
        async with http.post(f"{url}/api/sim/objects", json={"x": 1.3, "y": 0.0}) as answer:
            assert answer.status == 200
        status, answer = await post(http, url, {"object": [1.3, 0.0], "drop": [0.0, 1.2]})
        assert status == 200, answer

        async def ended() -> dict[str, Any] | None:
            async with http.get(f"{url}/api/fetch") as response:
                state: dict[str, Any] = await response.json()
            return state if state["state"] == "IDLE" else None

        state = await eventually(ended, "the fetch to end", within_s=120.0)
        assert state["result"] == "succeeded", state["reason"]
        async with http.get(f"{url}/api/sim/objects") as response:
            [item] = (await response.json())["objects"]
        assert not item["held"] and item["contacts"] == 0
        assert math.hypot(item["x"] - 0.0, item["y"] - 1.2) <= 0.10

        def fetch_state(m: dict[str, Any]) -> dict[str, Any] | None:
            return json.loads(m["msg"]["data"]) if m.get("topic") == "/fetch/state" else None

        await client.expect(lambda m: (fetch_state(m) or {}).get("result") == "succeeded",
                            what="/fetch/state: succeeded")
        seen: list[str] = []
        for m in client.received:
            state = fetch_state(m)
            if state is not None and (not seen or seen[-1] != state["state"]):
                seen.append(state["state"])
        assert seen[-5:] == ["NAV_TO_OBJECT", "GRASP", "NAV_TO_DROP", "DELIVER", "IDLE"]
