# `arbiterd fleet` with three real simulated robots (subprocesses) on loopback.
from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import pytest

from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.fleet import FleetSubprocess, robot_toml
from tests.support.net import http
from tests.support.wait import wait_for

pytest.importorskip("zenoh")
ROBOTS = 3


def _robots(fleet: FleetSubprocess) -> dict[str, dict]:
    status, body = http("GET", fleet.url + "/api/robots")
    assert status == 200, body
    return {r["robot_id"]: r for r in body}


@pytest.mark.timeout(240)
def test_three_robots_listed_stopped_and_dropped(tmp_path: Path) -> None:
    with ExitStack() as stack:
        fleet = stack.enter_context(FleetSubprocess(tmp_path))
        robots = []
        for n in range(1, ROBOTS + 1):
            (tmp_path / f"r{n}").mkdir()
            robots.append(stack.enter_context(DaemonSubprocess(
                tmp_path / f"r{n}", robot_toml(fleet.endpoint, n), args=("--sim",))))
        names = {f"robot{n}" for n in range(1, ROBOTS + 1)}

        def all_listed() -> bool:
            listed = _robots(fleet)
            return names <= set(listed) and all(
                listed[n]["online"] and listed[n]["pose"] is not None
                and listed[n]["health"] in ("ok", "degraded")
                and listed[n]["estop_engaged"] is False for n in names)

        wait_for(all_listed, lambda: f"all {ROBOTS} robots listed: {_robots(fleet)}",
                 within_s=30.0)
        listed = _robots(fleet)
        for name in names:
            assert set(listed[name]["pose"]) >= {"x", "y", "theta"}
            assert listed[name]["last_seen"] > 0 and listed[name]["console"]
        # a wrong type is named; releasing needs the token
        assert http("POST", fleet.url + "/api/robots/robot1/estop",
                    {"engaged": "yes"})[0] == 422
        assert http("POST", fleet.url + "/api/robots/robot1/estop",
                    {"engaged": False})[0] == 401
        status, answer = http("POST", fleet.url + "/api/stop_all")
        assert status == 200, answer
        assert set(answer["stopped"]) == names and answer["silent"] == [], answer
        for robot in robots:
            status, body = robot.get("/api/status")
            assert status == 200 and body["estop"]["engaged"] is True, body
        # a robot that dies drops out: its liveliness token goes, last_seen stops
        robots[0].stop()
        wait_for(lambda: not _robots(fleet)["robot1"]["online"], "robot1 to drop out",
                 within_s=15.0)
        gone = _robots(fleet)["robot1"]
        wait_for(lambda: _robots(fleet)["robot1"]["stale"], "robot1 stale", within_s=10.0)
        assert _robots(fleet)["robot1"]["last_seen"] == gone["last_seen"]
        assert _robots(fleet)["robot2"]["online"]
