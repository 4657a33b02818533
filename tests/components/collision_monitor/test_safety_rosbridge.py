# rosbridge: /autonomy/mode switches the behaviour; /autonomy/state and /collision_monitor/state
# report; a tokenless client may read them but not switch it.
from __future__ import annotations

import json
from pathlib import Path

from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rosbridge import connect
from tests.support.wait import eventually


async def test_autonomy_mode_topic_and_both_state_topics(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as client:
        await client.send(op="subscribe", topic="/autonomy/state", id="a")
        await client.send(op="subscribe", topic="/collision_monitor/state", id="c")
        await client.send(op="advertise", topic="/autonomy/mode", type="std_msgs/msg/String")
        await client.send(op="publish", topic="/autonomy/mode", msg={"data": "wander"})
        state = await client.expect(
            lambda m: m.get("topic") == "/autonomy/state" and
            json.loads(m["msg"]["data"])["mode"] == "wander", what="wander on /autonomy/state")
        assert json.loads(state["msg"]["data"])["state"] in ("CRUISE", "AVOID", "ROTATE")
        await eventually(robot.moving, "the robot to wander")
        safety = await client.expect(lambda m: m.get("topic") == "/collision_monitor/state",
                                     what="the collision monitor's state")
        body = json.loads(safety["msg"]["data"])
        assert set(body) >= {"action", "zone", "nearest_m", "scan_age_s"}
        await client.send(op="publish", topic="/autonomy/mode", msg={"data": "off"})
        await eventually(lambda: robot.component("autonomy").mode == "off", "mode off")


async def test_a_bad_mode_is_a_status_error(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as client:
        await client.send(op="advertise", topic="/autonomy/mode", type="std_msgs/msg/String")
        await client.send(op="publish", topic="/autonomy/mode", msg={"data": "dance"}, id="p")
        status = await client.op("status", id="p")
        assert status["level"] == "error" and "wander" in status["msg"]
        assert robot.component("autonomy").mode == "off"


async def test_switching_autonomy_needs_the_token(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, '[security]\ntoken = "open-sesame-1"\n') as robot, \
            connect(robot.ws_url) as client:
        await client.send(op="subscribe", topic="/autonomy/state")  # reading is open
        await client.expect(lambda m: m.get("topic") == "/autonomy/state", what="a state")
        await client.send(op="advertise", topic="/autonomy/mode", type="std_msgs/msg/String",
                          id="adv")
        status = await client.op("status", id="adv")
        assert status["level"] == "error" and "token" in status["msg"]
        assert robot.component("autonomy").mode == "off"
