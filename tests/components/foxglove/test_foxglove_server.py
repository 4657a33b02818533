# The Foxglove WebSocket server against the in-process daemon: greeting, channels, messages,
# client publishing under the token, parameters, time.
from __future__ import annotations

import json
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from daemon.messages import cdr
from daemon.messages.cdr_read import decode
from daemon.messages.msgtypes import full_text
from tests.support.foxglove import connect, publish_frame, upgrade_status
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.net import free_port
from tests.support.rosbridge import OWNER, TOKEN, TWIST, WITH_TOKEN
from tests.support.wait import eventually

STOP = {"linear": {"x": 0.0, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}


@pytest.fixture
async def fox(tmp_path: Path) -> AsyncIterator[InProcessDaemon]:
    """The simulated robot with [foxglove] on a free port (``fox.fox_url``) and a token."""
    port = free_port()
    async with in_process_daemon(tmp_path, f'[foxglove]\nenabled = true\nhost = "127.0.0.1"\n'
                                           f'port = {port}\n' + WITH_TOKEN) as robot:
        robot.fox_url = f"ws://127.0.0.1:{port}/"  # type: ignore[attr-defined]
        yield robot


def url(robot: InProcessDaemon) -> str:
    return str(robot.fox_url)  # type: ignore[attr-defined]


@pytest.mark.parametrize("subprotocol", ["foxglove.sdk.v1", "foxglove.websocket.v1"])
async def test_server_info_then_every_outgoing_topic_advertised(fox: InProcessDaemon,
                                                                subprotocol: str) -> None:
    async with connect(url(fox), protocols=(subprotocol,)) as client:
        assert client.ws.protocol == subprotocol
        await client.op("advertise")
        first, second = client.ops[:2]
        assert first["op"] == "serverInfo" and second["op"] == "advertise"
        assert {"clientPublish", "parameters", "time"} <= set(first["capabilities"])
        assert "cdr" in first["supportedEncodings"]
        assert first["metadata"]["ROS_DISTRO"]
        channels = {c["topic"]: c for c in second["channels"]}
        outgoing = {t.name: t.type for t in fox.ctx.topics.outgoing()}
        assert set(channels) == set(outgoing)
        assert "/scan" in channels and "/odom" in channels and "/tf" in channels
        for name, channel in channels.items():
            assert channel["schemaName"] == outgoing[name]
            assert (channel["encoding"], channel["schemaEncoding"]) == ("cdr", "ros2msg")
            assert channel["schema"] == full_text(outgoing[name])
        assert len({c["id"] for c in channels.values()}) == len(channels)


async def test_subscribed_scan_arrives_as_cdr_and_stops_on_unsubscribe(
        fox: InProcessDaemon) -> None:
    async with connect(url(fox)) as client:
        scan = (await client.channels())["/scan"]
        await client.send(op="subscribe", subscriptions=[{"id": 7, "channelId": scan["id"]}])
        await client.until(lambda: len(client.messages.get(7, [])) >= 2, "two scans")
        t_ns, payload = client.messages[7][-1]
        msg = decode("sensor_msgs/msg/LaserScan", payload)
        assert msg["header"]["frame_id"] and len(msg["ranges"]) > 100
        assert t_ns > 1_600_000_000 * 10**9 and client.times  # wall clock, with time frames
        await client.send(op="unsubscribe", subscriptionIds=[7])
        count = len(client.messages[7])
        statuses = await client.statuses(0.5)
        assert len(client.messages[7]) <= count + 1  # at most one already on its way
        assert statuses == []
    await eventually(lambda: fox.component("foxglove").health().values[
        "subscribed_channels"] == 0, "the bus subscription dropped")


async def test_a_state_topic_sends_its_latest_message_on_subscribe(fox: InProcessDaemon) -> None:
    async with connect(url(fox)) as client:
        info = (await client.channels())["/robot_info"]
        await client.send(op="subscribe", subscriptions=[{"id": 1, "channelId": info["id"]}])
        await client.until(lambda: client.messages.get(1), "the latest /robot_info")


@pytest.mark.parametrize("encoding", ["cdr", "json"])
async def test_cmd_vel_with_the_token_drives_and_a_disconnect_brakes(
        fox: InProcessDaemon, encoding: str) -> None:
    payload = cdr.encode("geometry_msgs/msg/Twist", TWIST) if encoding == "cdr" \
        else json.dumps(TWIST).encode()
    async with connect(url(fox), headers=OWNER) as client:
        await client.send(op="advertise", channels=[{
            "id": 3, "topic": "/cmd_vel", "encoding": encoding,
            "schemaName": "geometry_msgs/Twist"}])
        await client.ws.send_bytes(publish_frame(3, payload))
        await eventually(fox.moving, "the wheels to turn")
        assert [o for o in client.ops if o["op"] == "status"] == []
    await eventually(lambda: not fox.moving(), "the robot to brake when the client left")


async def test_the_token_in_the_url_also_gives_drive_access(fox: InProcessDaemon) -> None:
    async with connect(url(fox) + f"?token={TOKEN}") as client:
        await client.send(op="advertise", channels=[{
            "id": 1, "topic": "/cmd_vel", "encoding": "json",
            "schemaName": "geometry_msgs/msg/Twist"}])
        await client.ws.send_bytes(publish_frame(1, json.dumps(TWIST).encode()))
        await eventually(fox.moving, "the wheels to turn")


async def test_without_the_token_a_client_reads_but_never_moves_the_robot(
        fox: InProcessDaemon) -> None:
    async with connect(url(fox)) as client:
        scan = (await client.channels())["/scan"]
        await client.send(op="subscribe", subscriptions=[{"id": 1, "channelId": scan["id"]}])
        await client.send(op="advertise", channels=[{
            "id": 9, "topic": "/cmd_vel", "encoding": "json",
            "schemaName": "geometry_msgs/msg/Twist"}])
        refused = await client.op("status", "the advertise refused")
        assert refused["level"] == 2 and "token" in refused["message"], refused
        for _ in range(50):  # on the channel it was refused, and one it never advertised
            await client.ws.send_bytes(publish_frame(9, json.dumps(TWIST).encode()))
            await client.ws.send_bytes(publish_frame(1, json.dumps(TWIST).encode()))
        await client.until(lambda: len(client.messages.get(1, [])) >= 2, "scans meanwhile")
        statuses = await client.statuses(0.3)
        assert all(s["level"] == 2 for s in statuses)
        assert any("was not advertised" in s["message"] for s in statuses), statuses
    assert not fox.moving()
    assert fox.component("foxglove").health().values["published"] == 0


async def test_without_the_token_the_estop_latches_but_never_releases(
        fox: InProcessDaemon) -> None:
    async with connect(url(fox)) as client:
        await client.send(op="advertise", channels=[{
            "id": 1, "topic": "/estop", "encoding": "json", "schemaName": "std_msgs/msg/Bool"}])
        await client.ws.send_bytes(publish_frame(1, b'{"data": true}'))
        await eventually(lambda: fox.ctx.robot.estop_engaged, "the e-stop latched")
        await client.ws.send_bytes(publish_frame(1, b'{"data": false}'))
        refused = await client.op("status", "the release refused")
        assert "token" in refused["message"], refused
    assert fox.ctx.robot.estop_engaged


@pytest.mark.parametrize(("headers", "protocols", "status"), [
    ({"Host": "evil.example"}, ("foxglove.websocket.v1",), 403),
    ({"Origin": "http://evil.example"}, ("foxglove.websocket.v1",), 403),
    ({}, ("rosbridge",), 400),
    ({}, (), 400),
])
async def test_host_origin_and_subprotocol_are_checked_at_the_upgrade(
        fox: InProcessDaemon, headers: dict[str, str], protocols: tuple[str, ...],
        status: int) -> None:
    assert await upgrade_status(url(fox), headers, protocols) == status


async def test_robot_topics_and_wrong_types_cannot_be_advertised(fox: InProcessDaemon) -> None:
    async with connect(url(fox), headers=OWNER) as client:
        await client.send(op="advertise", channels=[{
            "id": 1, "topic": "/scan", "encoding": "cdr",
            "schemaName": "sensor_msgs/msg/LaserScan"}])
        await client.op("status", where=lambda o: "published by the robot" in o["message"])
        await client.send(op="advertise", channels=[{
            "id": 2, "topic": "/cmd_vel", "encoding": "cdr", "schemaName": "std_msgs/String"}])
        await client.op("status", where=lambda o: "not std_msgs/msg/String" in o["message"])
        await client.send(op="advertise", channels=[{
            "id": 3, "topic": "/cmd_vel", "encoding": "protobuf",
            "schemaName": "geometry_msgs/msg/Twist"}])
        await client.op("status", where=lambda o: "encoding 'protobuf'" in o["message"])


async def test_parameters_are_the_configuration_read_only(fox: InProcessDaemon) -> None:
    async with connect(url(fox)) as client:
        await client.send(op="getParameters", parameterNames=[], id="all")
        values = await client.op("parameterValues")
        assert values["id"] == "all"
        names = {p["name"]: p["value"] for p in values["parameters"]}
        assert names["robot.wheel_radius"] > 0
        assert not any(n.startswith("security.") for n in names)
        await client.send(op="setParameters", parameters=[
            {"name": "robot.wheel_radius", "value": 1.0}])
        refused = await client.op("status")
        assert "read-only" in refused["message"]


async def test_unadvertising_the_driving_channel_brakes(fox: InProcessDaemon) -> None:
    async with connect(url(fox), headers=OWNER) as client:
        await client.send(op="advertise", channels=[{
            "id": 1, "topic": "/cmd_vel", "encoding": "json",
            "schemaName": "geometry_msgs/msg/Twist"}])
        await client.ws.send_bytes(publish_frame(1, json.dumps(TWIST).encode()))
        await eventually(fox.moving, "the wheels to turn")
        await client.send(op="unadvertise", channelIds=[1])
        await eventually(lambda: not fox.moving(), "the robot to brake")
        assert [o for o in client.ops if o["op"] == "status"] == []


async def test_a_goal_pose_without_a_position_is_refused(fox: InProcessDaemon) -> None:
    """TopicIn.required holds on this transport too: no goal to (0, 0) from a JSON message
    that left its position out (the type's defaults would have filled it in)."""
    nav = fox.component("navigation")
    goals = nav.navigator.goals
    async with connect(url(fox), headers=OWNER) as client:
        await client.send(op="advertise", channels=[{
            "id": 4, "topic": "/goal_pose", "encoding": "json",
            "schemaName": "geometry_msgs/PoseStamped"}])
        await client.ws.send_bytes(publish_frame(4, json.dumps(
            {"header": {"frame_id": "odom"}, "pose": {"orientation": {"w": 1.0}}}).encode()))
        status = await client.op("status", "the refusal")
    assert "msg.pose.position: missing (required)" in status["message"], status
    assert nav.navigator.goals == goals and not fox.moving()
