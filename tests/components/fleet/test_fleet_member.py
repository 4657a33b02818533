# The fleet component against a real Zenoh router on loopback: telemetry, queryables, commands.
from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import pytest

from daemon.components.fleet import keys
from daemon.config import ConfigError
from daemon.messages import cdr
from daemon.messages.cdr_read import decode
from daemon.messages.definitions import BOOL, ODOMETRY, TWIST
from tests.support.fleet import (
    OPERATOR,
    OPERATOR_PASSWORD,
    ROBOT,
    ROBOT_PASSWORD,
    client,
    fleet_toml,
    zenoh_router,
)
from tests.support.in_process_daemon import in_process_daemon
from tests.support.wait import eventually

pytest.importorskip("zenoh")

ESTOP_ON = cdr.encode(BOOL, {"data": True})


def _get(session: Any, key: str, payload: bytes | None = None) -> list[tuple[bool, bytes]]:
    """Each reply of a query: (ok, payload)."""
    out = []
    for reply in session.get(key, payload=payload, timeout=2.0):
        if reply.ok is not None:
            out.append((True, reply.ok.payload.to_bytes()))
        else:
            out.append((False, reply.err.payload.to_bytes()))
    return out


async def _joined(session: Any, robot_id: str = "r1") -> None:
    """Until the robot's queryables answer through the router (declarations travel after the
    session opened)."""
    key = f"arbiterd/{robot_id}/srv/status"
    await eventually(lambda: asyncio.to_thread(_get, session, key), f"{robot_id} to answer")


async def test_robot_joins_publishes_and_answers(tmp_path: Path) -> None:
    with zenoh_router(tmp_path) as router:
        samples: dict[str, Any] = {}
        router.session.declare_subscriber(
            "arbiterd/**", lambda s: samples.__setitem__(str(s.key_expr), s))
        alive: list[str] = []
        router.session.liveliness().declare_subscriber(
            "arbiterd/*/alive", lambda s: alive.append(str(s.key_expr)), history=True)
        async with in_process_daemon(tmp_path, fleet_toml(router.endpoint)) as d:
            await eventually(lambda: "arbiterd/r1/alive" in alive, "the liveliness token")
            await eventually(lambda: "arbiterd/r1/odom" in samples, "odometry")
            odom = decode(ODOMETRY, samples["arbiterd/r1/odom"].payload.to_bytes())
            assert odom["child_frame_id"] == "base_link"
            await eventually(lambda: "arbiterd/r1/info" in samples, "the robot's info")
            info = json.loads(samples["arbiterd/r1/info"].payload.to_bytes())
            assert info["robot_id"] == "r1" and info["commands"] is True
            await _joined(router.session)
            replies = await asyncio.to_thread(_get, router.session, "arbiterd/r1/srv/status")
            assert replies and replies[0][0]
            status = json.loads(replies[0][1])
            assert status["estop_engaged"] is False and set(status["pose"]) == {"x", "y",
                                                                                 "theta"}
            fleet = d.daemon.component_health()["fleet"]
            assert fleet["status"] == "ok", fleet


async def test_operator_stop_latches_and_robot_user_cannot(tmp_path: Path) -> None:
    with zenoh_router(tmp_path) as router:
        async with in_process_daemon(tmp_path, fleet_toml(router.endpoint)) as d:
            robot = d.ctx.robot
            await _joined(router.session)
            # another robot's credentials: the router's access control drops the query
            other = await asyncio.to_thread(client, router.endpoint, ROBOT, ROBOT_PASSWORD)
            try:
                replies = await asyncio.to_thread(_get, other, "arbiterd/*/cmd/estop",
                                                  ESTOP_ON)
            finally:
                other.close()
            assert replies == [] and not robot.estop_engaged
            # the operator (allow_commands is off: the e-stop is still honoured)
            op = await asyncio.to_thread(client, router.endpoint, OPERATOR, OPERATOR_PASSWORD)
            try:
                replies = await asyncio.to_thread(_get, op, "arbiterd/*/cmd/estop", ESTOP_ON)
                assert replies and replies[0][0], replies
                assert robot.estop_engaged
                # driving needs allow_commands
                twist = cdr.encode(TWIST, {"linear": {"x": 0.1, "y": 0.0, "z": 0.0},
                                    "angular": {"x": 0.0, "y": 0.0, "z": 0.0}})
                replies = await asyncio.to_thread(_get, op, "arbiterd/r1/cmd/cmd_vel", twist)
                assert not replies[0][0] and b"allow_commands" in replies[0][1]
                garbage = await asyncio.to_thread(_get, op, "arbiterd/r1/cmd/estop",
                                                  b"\x00\x01\xff")
                assert not garbage[0][0] and b"/estop" in garbage[0][1]
                flood = await asyncio.to_thread(_get, op, "arbiterd/r1/cmd/estop",
                                                b"x" * 200_000)
                assert not flood[0][0]
            finally:
                op.close()


async def test_unauthenticated_peer_cannot_connect(tmp_path: Path) -> None:
    with zenoh_router(tmp_path) as router:
        with pytest.raises(Exception, match="Unable to connect"):
            await asyncio.to_thread(client, router.endpoint)
        with pytest.raises(Exception, match="Unable to connect"):
            await asyncio.to_thread(client, router.endpoint, OPERATOR, "wrong")


async def test_robot_without_credentials_cannot_join(tmp_path: Path) -> None:
    with zenoh_router(tmp_path) as router:
        async with in_process_daemon(tmp_path, fleet_toml(router.endpoint, user="",
                                                          password="")) as d:
            await eventually(lambda: d.daemon.component_health()["fleet"]
                             ["attempts"] >= 2, "two tries")
            fleet = d.daemon.component_health()["fleet"]
            assert fleet["status"] == "degraded" and "cannot reach" in fleet["problem"]


async def test_driving_from_the_fleet_goes_through_the_arbiter(tmp_path: Path) -> None:
    with zenoh_router(tmp_path) as router:
        toml = fleet_toml(router.endpoint, allow_commands=True)
        async with in_process_daemon(tmp_path, toml) as d:
            await _joined(router.session)
            twist = cdr.encode(TWIST, {"linear": {"x": 0.1, "y": 0.0, "z": 0.0},
                                    "angular": {"x": 0.0, "y": 0.0, "z": 0.0}})
            replies = await asyncio.to_thread(_get, router.session, "arbiterd/r1/cmd/cmd_vel",
                                              twist)
            assert replies and replies[0][0], replies
            await eventually(lambda: d.ctx.robot.odometry_speed() > 0.01,
                             "the robot to move")


def test_commands_without_credentials_are_a_config_error(tmp_path: Path) -> None:
    from daemon.config import load_config

    path = tmp_path / "a.toml"
    path.write_text(fleet_toml("tcp/127.0.0.1:7447", allow_commands=True, user="",
                               password=""))
    with pytest.raises((ValueError, ConfigError), match="allow_commands"):
        _build(load_config(path, sim=True))


def _build(config: Any) -> None:
    from daemon.components.fleet.component import create

    class Ctx:
        def settings(self, cls: Any) -> Any:
            return config.get(cls)

    create(Ctx())  # type: ignore[arg-type]


def test_key_space() -> None:
    assert keys.topic_key("r1", "/odom") == "arbiterd/r1/odom"
    assert keys.command_key("*", "/estop") == "arbiterd/*/cmd/estop"
    assert keys.split("arbiterd/r1/battery_state") == ("r1", "battery_state")
    assert keys.split("other/r1/x") is None
