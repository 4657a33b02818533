# A component's health is one typed value, and every transport shows the same problem.
from __future__ import annotations

from pathlib import Path

import pytest

from daemon.app import not_ok
from daemon.health import Health, problem_of, worst
from daemon.messages.convert import diagnostics_msg
from tests.support.in_process_daemon import in_process_daemon

WHY = "no answer from the board on /dev/ttyUSB0"


def test_a_status_other_than_ok_must_say_why() -> None:
    with pytest.raises(ValueError, match="needs a problem"):
        Health("degraded")
    with pytest.raises(ValueError, match="status must be one of"):
        Health("bad", "x")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="may not use the keys"):
        Health("ok", values={"problem": "hidden here"})


def test_a_device_report_names_its_reason_key() -> None:
    health = Health.of({"status": "error", "last_error": WHY, "port": "/dev/x"}, "last_error")
    assert (health.status, health.problem, health.values) == \
        ("error", WHY, {"last_error": WHY, "port": "/dev/x"})
    assert Health.of({"status": "degraded", "state": "connecting"}, "last_error",
                     otherwise="connecting").problem == "connecting"


def test_every_transport_renders_the_same_problem() -> None:
    rendered = Health("degraded", WHY, {"revolutions": 3}).to_json()
    assert rendered == {"status": "degraded", "problem": WHY, "revolutions": 3}
    assert problem_of(rendered) == WHY
    assert not_ok({"lidar": rendered}) == f"lidar degraded: {WHY}"  # arbiterd status, STATUS=
    message = diagnostics_msg({"status": "degraded", "components": {"lidar": rendered}})
    assert message["status"][1]["message"] == WHY  # /diagnostics, the recorder
    assert worst(["ok", "degraded", "ok"]) == "degraded"


async def test_every_component_of_the_running_daemon_reports_a_typed_health(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Navigation and fetch (on, with what they need missing) stay ``ok`` (nothing is wrong
    with the robot) but say what they cannot do in ``problem``: ``/api/health`` and
    ``/diagnostics`` show it."""
    monkeypatch.setenv("ARBITERD_SIM_LIDAR", "false")  # a robot without a lidar
    extra = "[navigation]\nenabled = true\n[fetch]\nenabled = true\n"
    async with in_process_daemon(tmp_path, extra) as robot:
        for component in robot.daemon.components:
            health = component.health()
            assert health is None or isinstance(health, Health), component.name
        components = robot.daemon.health()["components"]
        assert "no lidar" in components["navigation"]["problem"]
        assert components["fetch"]["status"] == "ok" and "[arm]" in components["fetch"]["problem"]
        diagnostics = diagnostics_msg(robot.daemon.health())["status"]
        assert any("no lidar" in status["message"] for status in diagnostics)
