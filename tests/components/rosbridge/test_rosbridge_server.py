# rosbridge v2 over a real WebSocket against the in-process daemon (mock driver, simulated mode).
from __future__ import annotations

import asyncio
import itertools
import json
import logging
import time
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from daemon.telemetry import ROBOT_INFO, SCAN
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rosbridge import TIMEOUT, TWIST, FakeScan, bridge, connect, upgrade_status
from tests.support.wait import eventually

# -- driving ---------------------------------------------------------------------------------


@pytest.mark.parametrize("spelling", ["geometry_msgs/Twist", "geometry_msgs/msg/Twist"])
async def test_cmd_vel_drives_with_either_type_spelling(robot: InProcessDaemon,
                                                        spelling: str) -> None:
    async with connect(robot.ws_url) as client:
        await client.send(op="advertise", topic="/cmd_vel", type=spelling, id="adv")
        await client.send(op="publish", topic="/cmd_vel", msg=TWIST)
        await eventually(robot.moving, "the wheels to turn")
        reply = await client.call("/rosapi/topic_type", {"topic": "/cmd_vel"})
        assert reply["values"] == {"type": "geometry_msgs/msg/Twist"}
        assert not [m for m in client.received if m.get("op") == "status"]


async def test_twist_stamped_on_cmd_vel_and_publish_without_advertise(
        robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as client:
        await client.send(op="publish", topic="cmd_vel", msg={
            "header": {"stamp": {"secs": 1, "nsecs": 2}, "frame_id": "base_link"},
            "twist": TWIST})
        await eventually(robot.moving, "the wheels to turn")


async def test_bad_command_is_a_status_error_and_no_motion(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as client:
        await client.send(op="advertise", topic="/cmd_vel", type="geometry_msgs/Twist")
        bad = [({"linear": {"x": "fast"}}, "msg.linear.x: expected float64"),
               ({"linear": {"x": 0.1, "y": 0.5}}, "linear.y"),
               ({"linear": {"x": 0.1}, "spin": 1}, "field 'spin'"),
               ({"linear": {"x": 0.1}, "angular": {"z": True}}, "angular.z")]
        for i, (msg, text) in enumerate(bad):
            await client.send(op="publish", topic="/cmd_vel", msg=msg, id=f"bad{i}")
            status = await client.op("status", id=f"bad{i}")
            assert status["level"] == "error" and text in status["msg"], status
        assert not robot.moving()
        assert robot.control.decision.source is None


async def test_stamped_command_gets_a_latency_report(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as client:
        await client.send(op="subscribe", topic="/latency_reports", type="std_msgs/String")
        await client.send(op="advertise", topic="/stamped_cmd_vel", type="std_msgs/msg/String")
        t_sent = time.time() * 1e3
        body = {"linear": {"x": 0.2}, "angular": {"z": 0.0}, "id": "cmd-1", "t_sent": t_sent}
        await client.send(op="publish", topic="/stamped_cmd_vel", msg={"data": json.dumps(body)})
        report_msg = await client.expect(
            lambda m: m.get("topic") == "/latency_reports"
            and json.loads(m["msg"]["data"])["id"] == "cmd-1", what="the latency report")
        report = json.loads(report_msg["msg"]["data"])
        assert report["t_sent"] == t_sent and report["source"].startswith("ws:")
        assert report["t_exec"] >= report["t_recv"] and report["exec_ms"] >= 0
        assert robot.daemon.latency.stats()["client_to_receipt_ms"]["count"] >= 1
        await client.send(op="publish", topic="/stamped_cmd_vel",
                          msg={"data": "{\"linear\": {\"x\": NaN}}"}, id="nan")
        status = await client.op("status", id="nan")
        assert "not a JSON command" in status["msg"]


async def test_estop_topic_latches_and_refuses_commands(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as client:
        await client.send(op="publish", topic="/estop", msg={"data": True})
        await eventually(lambda: robot.control.arbiter.estop_engaged, "the e-stop")
        await client.send(op="publish", topic="/cmd_vel", msg=TWIST, id="refused")
        status = await client.op("status", id="refused")
        assert "e-stop engaged" in status["msg"]
        assert not robot.moving()
        await client.send(op="publish", topic="/estop", msg={"data": False})
        await eventually(lambda: not robot.control.arbiter.estop_engaged, "the release")
        await client.send(op="publish", topic="/cmd_vel", msg=TWIST)
        await eventually(robot.moving, "the wheels to turn after release")


async def test_disconnect_while_driving_brakes_within_one_tick(robot: InProcessDaemon) -> None:
    ticks: list[float] = []
    control = robot.control
    control.on_tick.add(lambda now, on_time: ticks.append(now))
    drops: list[float] = []  # when the server learned of the disconnect
    drop_source = control.drop_source

    async def recording_drop(source: str) -> None:
        drops.append(time.monotonic())
        await drop_source(source)

    control.drop_source = recording_drop
    driver = robot.driver
    async with connect(robot.ws_url) as client:
        await client.send(op="advertise", topic="/cmd_vel", type="geometry_msgs/msg/Twist")

        async def speed_once_up() -> float | None:  # wheel rad/s at 0.3 m/s on 0.05 m wheels is 6
            await client.send(op="publish", topic="/cmd_vel",
                              msg={"linear": {"x": 0.3}, "angular": {"z": 0.0}})
            await asyncio.sleep(0.02)
            speed: float = driver.commands[-1].left_rad_s
            return speed if speed >= 3.0 else None

        speed = await eventually(speed_once_up, "the wheels up to speed", within_s=TIMEOUT,
                                 interval_s=0)
        t_close = time.monotonic()
    await eventually(lambda: drops, "the server to drop the client's command source")
    braking = await eventually(lambda: next(
        (c for c in driver.commands if c.t_mono > t_close and c.left_rad_s < speed), None),
        "a braking write")
    ticks_before = len([t for t in ticks if t <= drops[0]])
    await eventually(lambda: len(ticks) >= ticks_before + 2, "two more ticks")
    # braking starts on the disconnect itself, not at a later tick: at the latest it lands
    # behind a tick that was already running when the disconnect arrived
    assert braking.t_mono <= ticks[ticks_before + 1], "the brake waited for more than a tick"
    await eventually(lambda: driver.commands[-1].left_rad_s == 0.0, "the wheels to stop")
    assert robot.control.decision.reason in ("deadman: no valid command", "idle")


# -- telemetry ----------------------------------------------------------------------------------


async def test_odom_and_tf_follow_the_robot(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as client:
        await client.send(op="subscribe", topic="/odom", type="nav_msgs/Odometry")
        await client.send(op="subscribe", topic="/tf")
        await client.send(op="publish", topic="/cmd_vel", msg=TWIST)
        moved = await client.expect(lambda m: m.get("topic") == "/odom"
                                    and m["msg"]["pose"]["pose"]["position"]["x"] > 0.001,
                                    what="odometry showing motion")
        assert set(moved["msg"]["header"]["stamp"]) == {"sec", "nanosec"}
        assert len(moved["msg"]["pose"]["covariance"]) == 36
        tf = await client.op("publish", topic="/tf")
        transform = tf["msg"]["transforms"][0]
        assert (transform["header"]["frame_id"], transform["child_frame_id"]) == (
            "odom", "base_link")


async def test_scan_non_finite_ranges_arrive_as_null(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as client:
        await client.send(op="subscribe", topic="/scan", id="s")
        await client.call("/rosapi/get_time")  # the subscription is in place before publishing
        robot.ctx.bus.publish(SCAN, FakeScan())  # type: ignore[arg-type]
        scan = await client.expect(  # not one of the (emulated) lidar's own revolutions
            lambda m: m.get("topic") == "/scan" and
            m["msg"]["header"]["stamp"]["sec"] == int(FakeScan.stamp), what="the fake scan")
        assert scan["msg"]["ranges"][1:3] == [None, None]
        raw = client.raw[client.received.index(scan)]
        assert "NaN" not in raw and "Infinity" not in raw


async def test_a_scan_goes_out_after_the_next_control_tick(robot: InProcessDaemon) -> None:
    """A scan (a bulk topic) is encoded and sent in the wake-up of the control tick after it
    came, never at once: its encoding and ten clients' sends then cannot hold a tick up."""
    control, server = robot.control, bridge(robot)
    ticks: list[float] = []
    fanned_out: list[tuple[str, float]] = []
    fan_out = server.graph.fan_out

    def note_fan_out(topic: Any, shared: Any) -> None:
        fanned_out.append((topic.name, time.monotonic()))
        fan_out(topic, shared)

    remove = control.tick_sources.add(ticks.append)
    server.graph.fan_out = note_fan_out
    try:
        async with connect(robot.ws_url) as client:
            await client.send(op="subscribe", topic="/scan", id="s")
            await client.call("/rosapi/get_time")
            published = time.monotonic()
            robot.ctx.bus.publish(SCAN, FakeScan())  # type: ignore[arg-type]
            assert not [name for name, _ in fanned_out if name == "/scan"]  # not at once
            await client.expect(lambda m: m.get("topic") == "/scan" and m["msg"]["header"][
                "stamp"]["sec"] == int(FakeScan.stamp), what="the fake scan")
    finally:
        server.graph.fan_out = fan_out
        remove()
    sent = next(t for name, t in fanned_out if name == "/scan" and t >= published)
    assert any(published <= tick <= sent for tick in ticks)  # a tick came between


async def test_robot_info_latest_value_on_subscribe(robot: InProcessDaemon) -> None:
    await eventually(lambda: robot.ctx.bus.latest(ROBOT_INFO), "a robot_info")
    async with connect(robot.ws_url) as client:
        await client.send(op="subscribe", topic="/robot_info")
        info = await client.op("publish", topic="/robot_info")
        assert json.loads(info["msg"]["data"])["mode"] == "sim"


async def test_rosout_carries_daemon_log_lines(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as client:
        await client.send(op="subscribe", topic="/rosout", type="rcl_interfaces/msg/Log")
        await client.call("/rosapi/get_time")
        logging.getLogger("arbiterd.test").warning("hello from the daemon")
        line = await client.expect(lambda m: m.get("topic") == "/rosout"
                                   and m["msg"]["msg"] == "hello from the daemon")
        assert line["msg"]["level"] == 30 and line["msg"]["name"] == "arbiterd.test"


# -- protocol rules -------------------------------------------------------------------------------


async def test_throttle_rate_drops_messages_inside_the_window(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as pub, connect(robot.ws_url) as sub:
        await sub.send(op="subscribe", topic="/chatter", type="std_msgs/String",
                       throttle_rate=60000, id="slow")
        await sub.send(op="subscribe", topic="/marker", type="std_msgs/String")
        await sub.call("/rosapi/get_time")
        await pub.send(op="advertise", topic="/chatter", type="std_msgs/String")
        await pub.send(op="advertise", topic="/marker", type="std_msgs/String")
        for i in range(10):
            await pub.send(op="publish", topic="/chatter", msg={"data": str(i)})
        await pub.send(op="publish", topic="/marker", msg={"data": "end"})
        await sub.op("publish", topic="/marker")
        await sub.op("publish", topic="/chatter")
        assert sub.published("/chatter") == [{"data": "0"}]
        queues = [c.outbox.topics["/chatter"] for c in robot.component("rosbridge").clients.values()
                  if "/chatter" in c.outbox.topics]
        assert len(queues) == 1
        assert queues[0].dropped == 9 and not queues[0].queue


async def test_queue_length_keeps_the_newest_paced_by_throttle(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as pub, connect(robot.ws_url) as sub:
        await sub.send(op="subscribe", topic="/chatter", type="std_msgs/String",
                       throttle_rate=300, queue_length=3)
        await sub.call("/rosapi/get_time")
        await pub.send(op="advertise", topic="/chatter", type="std_msgs/String")
        for i in range(10):
            await pub.send(op="publish", topic="/chatter", msg={"data": str(i)})
        times: list[float] = []
        while not sub.published("/chatter") or sub.published("/chatter")[-1]["data"] != "9":
            await sub.count("publish", len(sub.published("/chatter")) + 1)
            times.append(time.monotonic())
        values = [int(m["data"]) for m in sub.published("/chatter")]
        assert values[-3:] == [7, 8, 9] and values == sorted(values)
        gaps = [b - a for a, b in itertools.pairwise(times)]
        assert all(gap >= 0.25 for gap in gaps), gaps


async def test_several_subscriptions_merge_and_unsubscribe_by_id(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as client:
        await client.send(op="subscribe", topic="/odom", throttle_rate=1000, id="a")
        await client.send(op="subscribe", topic="/odom", throttle_rate=50, id="b")
        await client.call("/rosapi/get_time")
        session = next(iter(robot.component("rosbridge").clients.values()))
        assert session.outbox.topics["/odom"].options.throttle_s == 0.05
        await client.send(op="unsubscribe", topic="/odom", id="b")
        await client.call("/rosapi/get_time", rid="second")
        assert session.outbox.topics["/odom"].options.throttle_s == 1.0
        await client.send(op="unsubscribe", topic="/odom")
        await client.call("/rosapi/get_time", rid="third")
        assert "/odom" not in session.outbox.topics
        assert session not in robot.component("rosbridge").graph.topics["/odom"].subscribers


async def test_fragments_in_both_directions(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as client:
        text = json.dumps({"op": "publish", "topic": "/cmd_vel", "msg": TWIST, "id": "big"})
        pieces = [text[i:i + 20] for i in range(0, len(text), 20)]
        for num, piece in reversed(list(enumerate(pieces))):
            await client.send(op="fragment", id="frag-1", data=piece, num=num,
                              total=len(pieces))
        await eventually(robot.moving, "the fragmented command to drive")
        await client.send(op="subscribe", topic="/odom", fragment_size=200)
        parts: list[dict[str, Any]] = []
        first = await client.op("fragment", num=0)
        parts.append(first)
        for num in range(1, first["total"]):
            parts.append(await client.op("fragment", id=first["id"], num=num))
        joined = json.loads("".join(p["data"] for p in parts))
        assert joined["op"] == "publish" and joined["topic"] == "/odom"
        assert all(len(p["data"]) <= 200 for p in parts)
        await client.send(op="fragment", id="x", data="a" * 10, num=0, total=2)
        await client.send(op="fragment", id="x", data="b" * 10, num=1, total=3)
        assert "'total' changed" in (await client.op("status", id="x"))["msg"]


async def test_fragmented_service_call_and_fragmented_response(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as client:
        text = json.dumps({"op": "call_service", "service": "/rosapi/topics_and_raw_types",
                           "id": "raw", "fragment_size": 500})
        await client.send(op="fragment", id="f", data=text[:30], num=0, total=2)
        await client.send(op="fragment", id="f", data=text[30:], num=1, total=2)
        first = await client.op("fragment", id="raw", num=0)
        parts = [first] + [await client.op("fragment", id="raw", num=n)
                           for n in range(1, first["total"])]
        response = json.loads("".join(p["data"] for p in parts))
        assert response["op"] == "service_response" and response["result"] is True


MALFORMED: list[tuple[Any, str]] = [
    ("{not json", "invalid JSON"),
    ("[]", "JSON object"),
    ('"text"', "JSON object"),
    ({"id": 1}, "missing field 'op'"),
    ({"op": 5, "id": 2}, "expected a string"),
    ({"op": "dance", "id": 3}, "unknown operation 'dance'"),
    ({"op": "advertise", "id": 4, "topic": "/x"}, "missing field 'type'"),
    ({"op": "advertise", "id": 5, "topic": "/x", "type": "bad"}, "not a type name"),
    ({"op": "advertise", "id": 6, "topic": "/x", "type": "nope/Missing"}, "unknown message"),
    ({"op": "advertise", "id": 7, "topic": 7, "type": "std_msgs/String"}, "'topic'"),
    ({"op": "advertise", "id": 8, "topic": "/cmd_vel", "type": "std_msgs/String"},
     "type conflict"),
    ({"op": "advertise", "id": 9, "topic": "/odom", "type": "nav_msgs/Odometry"},
     "published by the robot"),
    ({"op": "publish", "id": 10, "topic": "/nowhere", "msg": {}}, "not yet advertised"),
    ({"op": "publish", "id": 11, "topic": "/odom", "msg": {}}, "published by the robot"),
    ({"op": "publish", "id": 12, "topic": "/cmd_vel", "msg": []}, "expected an object"),
    ({"op": "publish", "id": 13, "topic": "/cmd_vel", "msg": {"linear": 1}},
     "msg.linear"),
    ({"op": "publish", "id": 14, "topic": "/estop", "msg": {"data": "yes"}}, "msg.data"),
    ({"op": "publish", "id": 15, "topic": "/cmd_vel", "type": "nav_msgs/Odometry",
      "msg": {}}, "type conflict"),
    ({"op": "subscribe", "id": 16}, "missing field 'topic'"),
    ({"op": "subscribe", "id": 17, "topic": "/unknown"}, "unknown topic"),
    ({"op": "subscribe", "id": 18, "topic": "/odom", "type": "std_msgs/String"},
     "type conflict"),
    ({"op": "subscribe", "id": 19, "topic": "/odom", "throttle_rate": "fast"},
     "throttle_rate"),
    ({"op": "subscribe", "id": 20, "topic": "/odom", "queue_length": -1}, "queue_length"),
    ({"op": "subscribe", "id": 21, "topic": "/odom", "queue_length": 1.5}, "queue_length"),
    ({"op": "subscribe", "id": 22, "topic": "/odom", "fragment_size": "x"}, "fragment_size"),
    ({"op": "subscribe", "id": 23, "topic": "/odom", "compression": "zip"}, "compression"),
    ({"op": "subscribe", "id": 24, "topic": "/odom", "type": 3}, "type"),
    ({"op": "unadvertise", "id": 25, "topic": "/never"}, "not advertised"),
    ({"op": "call_service", "id": 26}, "missing field 'service'"),
    ({"op": "call_service", "id": 27, "service": ["/x"]}, "'service'"),
    ({"op": "service_response", "id": 28, "service": "/x", "result": True}, "no call"),
    ({"op": "service_response", "id": 29, "service": "/x"}, "missing field 'result'"),
    ({"op": "set_level", "id": 30, "level": "loud"}, "level"),
    ({"op": "fragment", "data": "x", "num": 0, "total": 1}, "missing field 'id'"),
    ({"op": "fragment", "id": 32, "data": 5, "num": 0, "total": 1}, "'data'"),
    ({"op": "fragment", "id": 33, "data": "x", "num": 3, "total": 1}, "num"),
    ({"op": "fragment", "id": 34, "data": "{broken", "num": 0, "total": 1}, "invalid JSON"),
    ({"op": "advertise_service", "id": 35, "service": "/s", "type": "bad"}, "type"),
    ({"op": "advertise_service", "id": 36, "service": "/rosapi/topics",
      "type": "rosapi/Topics"}, "provided by the daemon"),
    ({"op": "unadvertise_service", "id": 37, "service": "/s"}, "not advertised"),
    ({"op": "publish", "id": 38, "topic": "/a b", "msg": {}}, "not a valid ROS name"),
    ({"op": "advertise", "id": 39, "topic": "/x", "type": "std_msgs/String",
      "latch": "yes"}, "latch"),
    ({"op": "call_service", "id": 40, "service": "/rosapi/get_time", "timeout": "soon"},
     "timeout"),
    ({"op": "publish", "id": 41, "topic": "/stamped_cmd_vel", "msg": {"data": "[1]"}},
     "JSON object"),
    ({"op": "publish", "id": 42, "topic": "/stamped_cmd_vel",
      "msg": {"data": json.dumps({"linear": {"x": 0.1}, "t_sent": "now"})}}, "t_sent"),
    ({"op": "publish", "id": 43, "topic": "/stamped_cmd_vel",
      "msg": {"data": json.dumps({"linear": {"x": 0.1}, "id": [1]})}}, "data.id"),
    ({"op": "subscribe", "id": 44, "topic": "/odom", "fragment_size": 0}, "fragment_size"),
    ({"op": "publish", "id": 45, "topic": "/cmd_vel", "msg": {"linear": {"x": 1e39},
                                                               "extra": 1}}, "extra"),
    ({"op": "advertise", "id": 46, "topic": "", "type": "std_msgs/String"}, "topic"),
    ({"op": "publish", "id": "forty-seven", "topic": "/cmd_vel",
      "msg": {"angular": {"z": None}}}, "angular.z"),
]


async def test_fifty_malformed_frames_give_fifty_status_errors_and_a_live_socket(
        robot: InProcessDaemon) -> None:
    assert len(MALFORMED) == 50
    async with connect(robot.ws_url) as client:
        for frame, _ in MALFORMED:
            await client.ws.send_str(frame if isinstance(frame, str) else json.dumps(frame))
        statuses = await client.count("status", len(MALFORMED))
        for (frame, fragment), status in zip(MALFORMED, statuses, strict=True):
            assert status["level"] == "error"
            assert fragment in status["msg"], (frame, status)
            expected_id = frame.get("id") if isinstance(frame, dict) else None
            if isinstance(frame, dict) and frame.get("op") == "fragment":
                expected_id = frame.get("id") if frame.get("data") != "{broken" else None
            assert status.get("id") == expected_id, (frame, status)
        reply = await client.call("rosapi/get_time", rid="alive")
        assert reply["result"] is True
        assert not robot.moving()


# -- client topics and services -------------------------------------------------------------------


async def test_client_topics_relay_time_bytes_and_latch(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as pub, connect(robot.ws_url) as sub:
        await pub.send(op="advertise", topic="/stamped", type="geometry_msgs/TwistStamped")
        await pub.send(op="advertise", topic="/blob", type="std_msgs/UInt8MultiArray",
                       latch=True)
        await pub.send(op="publish", topic="/blob", msg={"data": [1, 2, 3]})
        await pub.call("/rosapi/get_time")
        await sub.send(op="subscribe", topic="/stamped", type="geometry_msgs/msg/TwistStamped")
        await sub.send(op="subscribe", topic="/blob")
        blob = await sub.op("publish", topic="/blob")
        assert blob["msg"]["data"] == "AQID"
        await sub.call("/rosapi/get_time")
        await pub.send(op="publish", topic="/stamped", msg={
            "header": {"stamp": {"secs": 5, "nsecs": 7}, "frame_id": "x"}, "twist": TWIST})
        stamped = await sub.op("publish", topic="/stamped")
        assert stamped["msg"]["header"]["stamp"] == {"sec": 5, "nanosec": 7}
        types = (await sub.call("/rosapi/topics"))["values"]
        assert types["types"][types["topics"].index("/blob")] == "std_msgs/msg/UInt8MultiArray"
        await pub.send(op="unadvertise", topic="/stamped")
        await pub.call("/rosapi/get_time", rid="after")
    async with connect(robot.ws_url) as third:
        topics = (await third.call("/rosapi/topics"))["values"]["topics"]
        assert "/blob" not in topics and "/stamped" not in topics


async def test_client_provided_service_round_trip(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as provider, connect(robot.ws_url) as caller:
        await provider.send(op="advertise_service", service="/add", type="example/AddTwo")
        await provider.call("/rosapi/get_time")
        assert (await caller.call("/rosapi/service_type", {"service": "add"}))["values"] == {
            "type": "example/srv/AddTwo"}
        await caller.send(op="call_service", service="add", id="q1", args={"a": 1, "b": 2})
        request = await provider.op("call_service", service="/add")
        assert request["args"] == {"a": 1, "b": 2}
        await provider.send(op="service_response", service="/add", id=request["id"],
                            values={"sum": 3}, result=True)
        answer = await caller.op("service_response", id="q1")
        assert answer == {"op": "service_response", "service": "add", "values": {"sum": 3},
                          "result": True, "id": "q1"}
        await caller.send(op="call_service", service="/add", id="q2", args={"a": 2})
        await provider.op("call_service", service="/add", id="service_request:/add:2")
    failed = await caller_failure(robot)
    assert failed["values"] == "Service /nothing does not exist"


async def caller_failure(robot: InProcessDaemon) -> dict[str, Any]:
    async with connect(robot.ws_url) as client:
        return await client.call("/nothing")


async def test_pending_call_fails_when_the_provider_leaves(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url) as caller:
        async with connect(robot.ws_url) as provider:
            await provider.send(op="advertise_service", service="/slow", type="x/Y")
            await provider.call("/rosapi/get_time")
            await caller.send(op="call_service", service="/slow", id="wait")
            await provider.op("call_service", service="/slow")
        answer = await caller.op("service_response", id="wait")
        assert answer["result"] is False and "unadvertised" in answer["values"]


# -- rosapi -------------------------------------------------------------------------------------


@pytest.mark.parametrize("prefix", ["/rosapi/", "rosapi/"])
async def test_rosapi_services_with_and_without_slash(robot: InProcessDaemon, prefix: str) -> None:
    async with connect(robot.ws_url) as client:
        topics = (await client.call(prefix + "topics", rid="t"))
        assert topics["service"] == prefix + "topics" and topics["result"] is True
        table = dict(zip(topics["values"]["topics"], topics["values"]["types"], strict=True))
        assert table["/odom"] == "nav_msgs/msg/Odometry"
        assert table["/rosout"] == "rcl_interfaces/msg/Log"
        assert table["/odom_ground_truth"] == "nav_msgs/msg/Odometry"  # sim mode
        for name in ("/cmd_vel", "/stamped_cmd_vel", "/estop", "/tf", "/scan", "/robot_info",
                     "/latency_reports"):
            assert name in table
        raw = (await client.call(prefix + "topics_and_raw_types", rid="r"))["values"]
        assert len(raw["typedefs_full_text"]) == len(raw["topics"])
        log_def = raw["typedefs_full_text"][raw["topics"].index("/rosout")]
        assert "string msg" in log_def and "MSG: builtin_interfaces/Time" in log_def
        assert (await client.call(prefix + "topics_for_type",
                                  {"type": "nav_msgs/Odometry"}))["values"]["topics"] == [
            "/odom", "/odom_ground_truth"]
        services = (await client.call(prefix + "services", rid="s"))["values"]["services"]
        assert "/rosapi/topics_and_raw_types" in services
        assert (await client.call(prefix + "service_type", ["/rosapi/nodes"]))["values"] == {
            "type": "rosapi_msgs/srv/Nodes"}
        nodes = (await client.call(prefix + "nodes"))["values"]["nodes"]
        assert "/arbiterd" in nodes
        details = (await client.call(prefix + "node_details", {"node": "/arbiterd"}))
        assert "/odom" in details["values"]["publishing"]
        assert "/cmd_vel" in details["values"]["subscribing"]
        assert (await client.call(prefix + "publishers", {"topic": "/odom"}))["values"] == {
            "publishers": ["/arbiterd"]}
        assert (await client.call(prefix + "subscribers", {"topic": "/cmd_vel"}))[
            "values"] == {"subscribers": ["/arbiterd"]}
        now = (await client.call(prefix + "get_time"))["values"]["time"]
        assert abs(now["sec"] + now["nanosec"] / 1e9 - time.time()) < 60
        assert (await client.call(prefix + "get_ros_version"))["values"]["version"] == 2
        bad = await client.call(prefix + "topic_type", {"topic": 5}, rid="bad")
        assert bad["result"] is False and "expected a string" in bad["values"]
        unknown = await client.call(prefix + "node_details", {"node": "/ghost"}, rid="ghost")
        assert unknown["result"] is False


# -- admission ----------------------------------------------------------------------------------


async def test_read_only_without_token_and_driving_with_it(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, '[security]\ntoken = "s3cret-t0ken"\n') as robot:
        async with connect(robot.ws_url) as anonymous:
            await anonymous.send(op="subscribe", topic="/odom")
            await anonymous.op("publish", topic="/odom")
            await anonymous.send(op="advertise", topic="/cmd_vel", type="geometry_msgs/Twist",
                                 id="adv")
            assert "needs a valid token" in (await anonymous.op("status", id="adv"))["msg"]
            await anonymous.send(op="publish", topic="/cmd_vel", msg=TWIST, id="pub")
            assert "needs a valid token" in (await anonymous.op("status", id="pub"))["msg"]
            await anonymous.send(op="publish", topic="/estop", msg={"data": False}, id="rel")
            assert "needs a valid token" in (await anonymous.op("status", id="rel"))["msg"]
            assert not robot.moving()
        async with connect(robot.ws_url + "?token=wrong") as wrong:
            await wrong.send(op="publish", topic="/cmd_vel", msg=TWIST, id="pub")
            await wrong.op("status", id="pub")
        async with connect(robot.ws_url + "?token=s3cret-t0ken") as by_query:
            await by_query.send(op="publish", topic="/cmd_vel", msg=TWIST)
            await eventually(robot.moving, "driving with ?token=")
        async with connect(robot.ws_url,
                           headers={"Authorization": "Bearer s3cret-t0ken"}) as header:
            await header.send(op="publish", topic="/cmd_vel", msg=TWIST, id="ok")
            await header.call("/rosapi/get_time")
            assert not [m for m in header.received if m.get("op") == "status"]


async def test_origin_allow_list(tmp_path: Path) -> None:
    config = '[security]\nallowed_origins = ["https://console.example"]\n'
    async with in_process_daemon(tmp_path, config) as robot:
        url = robot.ws_url
        assert await upgrade_status(url, Origin="https://evil.example") == 403
        assert await upgrade_status(url, Origin="http://localhost:3000") == 101
        assert await upgrade_status(url, Origin="https://console.example") == 101
        assert await upgrade_status(url, Origin="http://127.0.0.1:8080") == 101
        assert robot.component("rosbridge").refused["origin"] == 1


async def test_client_limit(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path) as robot:
        robot.component("rosbridge").max_clients = 2
        async with connect(robot.ws_url), connect(robot.ws_url) as second:
            await second.call("/rosapi/get_time")
            assert await upgrade_status(robot.ws_url) == 503
        await eventually(lambda: not robot.component("rosbridge").clients, "the clients to leave")
        assert await upgrade_status(robot.ws_url) == 101


async def test_plain_http_get_is_told_to_upgrade(robot: InProcessDaemon) -> None:
    async with aiohttp.ClientSession() as session, session.get(
            robot.ws_url.replace("ws://", "http://")) as response:
        assert response.status == 426

