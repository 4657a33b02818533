# The rosbridge access table, walked with a token configured: every drive op is refused without it.
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from daemon.components.rosbridge import access
from daemon.components.rosbridge.access import ANY, TABLE
from daemon.components.rosbridge.session import OPS, TARGET_FIELDS, ClientSession
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rosbridge import TWIST, Client, connect, upgrade_status

TOKEN = "s3cret-t0ken"
SAMPLE_TOPIC = "/walk"
SAMPLE_SERVICE = "/walk_srv"
TYPES = {"/cmd_vel": "geometry_msgs/msg/Twist", "/stamped_cmd_vel": "std_msgs/msg/String",
         "/estop": "std_msgs/msg/Bool"}
MESSAGES: dict[str, dict[str, Any]] = {
    "/cmd_vel": TWIST, "/estop": {"data": True},
    "/stamped_cmd_vel": {"data": json.dumps({"linear": {"x": 0.3}, "angular": {"z": 0.0}})},
}


def sample_target(op: str, target: str) -> str:
    if target != ANY:
        return target
    return SAMPLE_SERVICE if TARGET_FIELDS.get(op) == "service" else SAMPLE_TOPIC


def sample_frame(op: str, target: str, rid: str) -> dict[str, Any]:
    """A well-formed request for ``op`` on ``target``: only access can refuse it."""
    frame: dict[str, Any] = {"op": op, "id": rid}
    key = TARGET_FIELDS.get(op)
    if key is not None:
        frame[key] = target
    if op in ("advertise", "subscribe"):
        frame["type"] = TYPES.get(target, "std_msgs/msg/String")
    elif op == "publish":
        frame["msg"] = MESSAGES.get(target, {"data": "walk"})
    elif op == "advertise_service":
        frame["type"] = "example/Walk"
    elif op == "service_response":
        frame.update(result=True, values={})
    elif op == "set_level":
        frame["level"] = "error"
    elif op == "fragment":
        frame.update(data="{}", num=0, total=1)
    return frame


def drive_rules(robot: InProcessDaemon) -> list[tuple[str, str]]:
    """The table's drive rules, and advertising and publishing on every incoming topic the
    robot's components declare with drive access."""
    table = [(op, target) for (op, target), need in TABLE.items() if need == "drive"]
    topics = [(op, topic.name) for topic in robot.ctx.topics.incoming()
              if topic.access == "drive" for op in ("advertise", "publish")]
    return table + topics


# Incoming topics whose messages need more than the topic declares: one that needs drive each.
NEEDS_DRIVE = {"/estop": {"data": False}}


def per_message_rules(robot: InProcessDaemon) -> list[tuple[str, dict[str, Any]]]:
    """The incoming topics declaring a per-message access, with a message that needs drive."""
    found = [topic.name for topic in robot.ctx.topics.incoming() if topic.access_for]
    assert set(found) == set(NEEDS_DRIVE), found
    return [(name, NEEDS_DRIVE[name]) for name in found]


def test_the_table_covers_every_op_the_session_handles() -> None:
    assert {op for op, _ in TABLE} == set(OPS)
    assert all((op, ANY) in TABLE for op in OPS)
    assert all(callable(getattr(ClientSession, f"op_{op}")) for op in OPS)
    for name in ("/cmd_vel", "/stamped_cmd_vel", "/estop"):
        assert access.required("publish", name) == "drive"
        assert access.required("advertise", name) == "drive"
    # the robot's own /estop declares less: latching is "stop", releasing "drive"
    assert access.Authority(may_read=True, may_drive=False).allows("stop")


async def refused_for_access(client: Client, rid: str) -> bool:
    status = await client.op("status", id=rid)
    return "needs a valid token" in status["msg"]


async def no_access_refusals(client: Client) -> list[dict[str, Any]]:
    await client.call("/rosapi/get_time", rid="barrier")
    return [m for m in client.received if m.get("op") == "status"
            and "needs a valid token" in m.get("msg", "")]


async def test_every_drive_op_is_refused_without_the_token(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, f'[security]\ntoken = "{TOKEN}"\n') as robot:
        rules = drive_rules(robot)
        assert len(rules) >= 11
        messages = per_message_rules(robot)
        async with connect(robot.ws_url) as anonymous:
            for i, (op, target) in enumerate(rules):
                rid = f"walk-{i}"
                await anonymous.send(**sample_frame(op, sample_target(op, target), rid))
                assert await refused_for_access(anonymous, rid), (op, target)
            for i, (name, msg) in enumerate(messages):
                await anonymous.send(op="advertise", topic=name, type=TYPES[name])
                await anonymous.send(op="publish", topic=name, msg=msg, id=f"msg-{i}")
                assert await refused_for_access(anonymous, f"msg-{i}"), (name, msg)
                await anonymous.send(op="unadvertise", topic=name)
            await anonymous.call("/rosapi/get_time", rid="barrier")  # ops are taken in order
            assert_nothing_happened(robot)
        async with connect(robot.ws_url, headers={"Authorization": f"Bearer {TOKEN}"}) as owner:
            for i, (op, target) in enumerate(rules):
                await owner.send(**sample_frame(op, sample_target(op, target), f"own-{i}"))
            for name, msg in messages:
                await owner.send(op="publish", topic=name, msg=msg)
            assert await no_access_refusals(owner) == []


def assert_nothing_happened(robot: InProcessDaemon) -> None:
    assert not robot.moving()
    assert not robot.control.arbiter.estop_engaged
    graph = robot.component("rosbridge").graph
    assert not any(topic.publishers for topic in graph.topics.values())
    assert not graph.services and not graph.pending


async def test_read_and_open_ops_need_no_token(tmp_path: Path) -> None:
    config = f'[security]\ntoken = "{TOKEN}"\n'
    async with in_process_daemon(tmp_path, config) as robot, connect(robot.ws_url) as anonymous:
        for (op, target), need in TABLE.items():
            if need != "drive":
                await anonymous.send(**sample_frame(op, sample_target(op, target), f"{op}"))
        assert await no_access_refusals(anonymous) == []


async def test_read_requires_token_refuses_the_tokenless_upgrade(tmp_path: Path) -> None:
    config = f'[security]\ntoken = "{TOKEN}"\nread_requires_token = true\n'
    async with in_process_daemon(tmp_path, config) as robot:
        assert await upgrade_status(robot.ws_url) == 401
        assert await upgrade_status(robot.ws_url, Authorization=f"Bearer {TOKEN}") == 101
