# HTTP API of a running daemon: deadman stop, strict command validation, e-stop, token.
from __future__ import annotations

import re
from collections.abc import Iterator

import pytest

from tests.support.daemon_subprocess import DaemonSubprocess, StartDaemonSubprocess
from tests.support.paths import REPO
from tests.support.wait import wait_for

TIMEOUT_S = 0.3


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonSubprocess]:
    tmp = tmp_path_factory.mktemp("http")
    with DaemonSubprocess(tmp, f"[control]\ncmd_vel_timeout = {TIMEOUT_S}\n") as proc:
        yield proc


def moving(daemon: DaemonSubprocess) -> bool:
    rows = daemon.wheels()
    return bool(rows) and (rows[-1][1] != 0.0 or rows[-1][2] != 0.0)


def stopped(daemon: DaemonSubprocess) -> bool:
    return not moving(daemon)


def test_health_reports_state_mode_version(daemon: DaemonSubprocess) -> None:
    status, body = daemon.get("/api/health")
    assert status == 200
    assert body["status"] == "ok" and body["state"] == "ready"
    assert body["mode"] == "hardware" and body["version"]
    assert body["components"]["control"]["driver"]["driver"] == "mock"
    assert body["uptime_s"] >= 0


def test_deadman_stops_the_wheels_after_silence(daemon: DaemonSubprocess) -> None:
    wait_for(lambda: stopped(daemon), "the robot at rest", within_s=5)
    status, body = daemon.post("/api/cmd_vel", {"linear": {"x": 0.5}, "angular": {"z": 0.2}})
    assert status == 200 and body["accepted"], body
    wait_for(lambda: moving(daemon), "the wheels to move", within_s=2)
    wait_for(lambda: stopped(daemon), "the deadman stop", within_s=5)
    rows = daemon.wheels()
    last_rest = max(i for i, (_, left, right) in enumerate(rows) if (left, right) != (0.0, 0.0))
    first_motion = last_rest
    while first_motion > 0 and rows[first_motion - 1][1:] != (0.0, 0.0):
        first_motion -= 1
    t_start, t_stop = rows[first_motion][0], rows[last_rest + 1][0]
    peak = max(abs(left) for _, left, _ in rows[first_motion:last_rest + 1])
    # the ramp (1 m/s²) reaches ~0.3 m/s in 0.3 s; emergency decel (4 m/s²) needs < 0.1 s
    assert peak > 1.0
    assert TIMEOUT_S <= t_stop - t_start < TIMEOUT_S + 0.1 + 0.1
    status, body = daemon.get("/api/status")
    assert body["reason"] in ("idle", "deadman: no valid command")


BAD_BODIES = [
    ({"linear": {"x": "fast"}}, "linear.x: expected a number"),
    ({"linear": {"x": None}}, "linear.x: expected a number"),
    ({"linear": {"x": True}}, "linear.x: expected a number"),
    ({"linear": {"x": 0.1, "w": 2}}, "linear.w: unknown field"),
    ({"linear": 5}, "linear: expected an object"),
    ({"twist": {"x": 1}}, "twist: unknown field"),
    ({"linear": {"y": 0.5}}, "linear.y: a differential-drive base cannot move"),
    ({"linear": {"x": 0.1}, "id": [1]}, "id: expected a string or integer"),
    ({"linear": {"x": 0.1}, "t_sent": "now"}, "t_sent: expected a number"),
]


@pytest.mark.parametrize(("body", "message"), BAD_BODIES)
def test_bad_commands_are_refused_with_the_field_named(daemon: DaemonSubprocess, body: object,
                                                       message: str) -> None:
    before = len(daemon.wheels())
    status, answer = daemon.post("/api/cmd_vel", body)
    assert status == 422, answer
    assert message in answer["error"]
    assert stopped(daemon)
    assert all((left, right) == (0.0, 0.0) for _, left, right in daemon.wheels()[before:])


@pytest.mark.parametrize(("raw", "content_type", "status", "message"), [
    (b'{"linear": {"x": NaN}}', "application/json", 400, "NaN is not a valid JSON number"),
    (b'{"linear": {"x": Infinity}}', "application/json", 400, "Infinity"),
    (b"not json", "application/json", 400, "body is not valid JSON"),
    (b"[1, 2]", "application/json", 400, "body must be a JSON object"),
    (b'{"linear": {"x": 0.1}}', "text/plain", 415, "content type must be application/json"),
    (b"x" * 1_000_000, "application/json", 413, "body too large"),
])
@pytest.mark.parametrize("path", ["/api/cmd_vel", "/api/estop"])
def test_malformed_bodies_are_4xx_and_the_daemon_lives(daemon: DaemonSubprocess, path: str,
                                                       raw: bytes, content_type: str,
                                                       status: int, message: str) -> None:
    got, answer = daemon.post(path, raw=raw, content_type=content_type)
    assert got == status, answer
    assert message in answer["error"] + str(answer.get("detail"))
    assert daemon.get("/api/health")[0] == 200
    assert stopped(daemon)


def test_overflowing_number_is_refused_as_not_finite(daemon: DaemonSubprocess) -> None:
    status, answer = daemon.post("/api/cmd_vel", raw=b'{"linear": {"x": 1e400}}')
    assert status == 422 and "linear.x: must be finite" in answer["error"]
    assert stopped(daemon)


@pytest.mark.parametrize(("body", "message"), [
    ({}, "engaged: expected true or false"),
    ({"engaged": "yes"}, "engaged: expected true or false"),
    ({"engaged": True, "why": 1}, "why: unknown field"),
])
def test_bad_estop_requests(daemon: DaemonSubprocess, body: object, message: str) -> None:
    status, answer = daemon.post("/api/estop", body)
    assert status == 422 and message in answer["error"]


def test_estop_latches_until_released_and_a_fresh_command(daemon: DaemonSubprocess) -> None:
    assert daemon.post("/api/cmd_vel", {"linear": {"x": 0.5}})[0] == 200
    wait_for(lambda: moving(daemon), "motion", within_s=2)
    assert daemon.post("/api/estop", {"engaged": True})[1] == {"engaged": True}
    wait_for(lambda: stopped(daemon), "the e-stop brake", within_s=2)
    status, answer = daemon.post("/api/cmd_vel", {"linear": {"x": 0.5}})
    assert status == 409 and "e-stop engaged" in answer["error"]
    assert daemon.get("/api/status")[1]["estop"]["engaged"] is True
    assert daemon.post("/api/estop", {"engaged": False})[1] == {"engaged": False}
    assert stopped(daemon)
    assert daemon.post("/api/cmd_vel", {"linear": {"x": 0.2}})[0] == 200
    wait_for(lambda: moving(daemon), "motion after the release", within_s=2)


def test_out_of_range_is_clamped_and_reported(daemon: DaemonSubprocess) -> None:
    status, answer = daemon.post("/api/cmd_vel", {"linear": {"x": 50.0}})
    assert status == 200 and answer["clamped"] == ["linear.x"]
    status, body = daemon.get("/api/status")
    assert body["clamps"]["linear.x"] >= 1
    assert body["target"]["linear_x"] == 50.0
    wait_for(lambda: stopped(daemon), "the deadman stop", within_s=5)


def test_stamped_command_latency_is_tracked(daemon: DaemonSubprocess) -> None:
    import time

    status, answer = daemon.post("/api/cmd_vel", {"linear": {"x": 0.1}, "id": "c-7",
                                                  "t_sent": time.time() * 1e3})
    assert status == 200 and answer["id"] == "c-7" and answer["exec_ms"] >= 0
    status, latency = daemon.get("/api/latency")
    assert latency["commands"] >= 1
    assert latency["receipt_to_exec_ms"]["count"] >= 1
    assert latency["client_to_receipt_ms"]["count"] >= 1
    assert latency["client_to_receipt_ms"]["clock_dependent"] is True
    assert latency["per_source"]["http"] >= 1
    assert latency["tick"]["count"] > 0 and "p99" in latency["tick"]["lateness_ms"]


def test_unknown_route_and_wrong_method_are_json(daemon: DaemonSubprocess) -> None:
    status, body = daemon.get("/api/nothing")
    assert status == 404 and "error" in body
    status, body = daemon.get("/api/cmd_vel")
    assert status == 405 and "error" in body and "POST" in body["detail"]


def test_metrics_and_robot_info(daemon: DaemonSubprocess) -> None:
    status, text = daemon.get("/metrics")
    assert status == 200 and "arbiterd_up 1" in text and "arbiterd_ticks_total" in text
    assert daemon.post("/api/cmd_vel", {"linear": {"x": 0.0}})[0] == 200
    status, text = daemon.get("/metrics")
    assert "# TYPE arbiterd_command_exec_seconds histogram" in text
    assert 'arbiterd_command_exec_seconds_bucket{le="0.001"}' in text
    assert "arbiterd_tick_lateness_seconds_count" in text
    assert 'arbiterd_commands_total{source="http"}' in text
    status, info = daemon.get("/api/robot_info")
    assert info["driver"] == "mock" and info["geometry"]["wheel_separation"] == 0.3


def test_token_guards_motion_but_not_health(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    daemon = daemon_subprocess("[security]\ntoken = \"s3cret-t0ken\"\n")
    status, body = daemon.post("/api/cmd_vel", {"linear": {"x": 0.1}})
    assert status == 401 and "token" in body["error"]
    assert daemon.post("/api/estop", {"engaged": False})[0] == 401  # latching needs none
    assert daemon.post("/api/cmd_vel", {"linear": {"x": 0.1}}, token="wrong")[0] == 401
    assert stopped(daemon)
    status, body = daemon.post("/api/cmd_vel", {"linear": {"x": 0.1}}, token="s3cret-t0ken")
    assert status == 200 and body["accepted"]
    assert daemon.get("/api/health")[0] == 200
    assert daemon.get("/api/status")[0] == 200


def test_the_documented_metrics_are_the_ones_served(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    """docs/http-api.md's /metrics table, name for name and type for type, against a simulated
    robot whose collision monitor runs."""
    text = (REPO / "docs" / "http-api.md").read_text().split("## `/metrics`")[1]
    documented = dict(re.findall(r"^\| `(arbiterd_\w+)` \| (\w+) \|", text, re.MULTILINE))
    daemon = daemon_subprocess('[sim]\ndriver = "mock"\n', args=("--sim",))
    assert daemon.post("/api/cmd_vel", {"linear": {"x": 0.0}})[0] == 200
    status, served = daemon.get("/metrics")
    assert status == 200
    types = dict(re.findall(r"^# TYPE (\w+) (\w+)$", served, re.MULTILINE))
    helps = set(re.findall(r"^# HELP (\w+) ", served, re.MULTILINE))
    families = {name: kind for name, kind in types.items() if not name.endswith("_created")}
    for sample in re.findall(r"^(\w+)[{ ]", served, re.MULTILINE):
        base = re.sub(r"_(bucket|sum|count|created)$", "", sample)
        assert sample in families or families.get(base) == "histogram" or (
            sample.endswith("_created") and (base in families or f"{base}_total" in families)
        ), f"{sample}: served without a # TYPE"
    assert families == documented
    assert set(families) <= helps
