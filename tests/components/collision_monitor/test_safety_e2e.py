# Real time, end to end: `arbiterd run --sim` driven at a wall over HTTP, then wandering on its own.
from __future__ import annotations

import time
from typing import Any

from daemon.components.collision_monitor.settings import CollisionMonitorSettings
from tests.support.daemon_subprocess import DaemonSubprocess, StartDaemonSubprocess
from tests.support.paths import REPO
from tests.support.wait import wait_for

WALL_X = 3.0  # tests/scenarios/wall.toml: the robot starts at x = 0 facing this wall
FOOTPRINT = 0.2  # [sim] footprint_radius default
STOP_MARGIN = CollisionMonitorSettings.stop_margin_m


def status(daemon: DaemonSubprocess) -> dict[str, Any]:
    code, body = daemon.get("/api/status")
    assert code == 200, body
    return body  # type: ignore[no-any-return]


def test_driving_at_a_wall_over_http_and_wandering(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    world = REPO / "tests" / "scenarios" / "wall.toml"
    daemon = daemon_subprocess(f'[sim]\ndriver = "mock"\nworld_file = "{world}"\n',
                            args=("--sim",))
    wait_for(lambda: status(daemon)["safety"]["zone"] != "unknown", "the first revolution")

    closest, actions = drive_at_the_wall(daemon, seconds=7.0)
    assert closest >= STOP_MARGIN, f"ground truth came within {closest:.3f} m of the wall"
    assert "stop" in actions  # held in front of the wall
    assert actions & {"limit", "slowdown"}  # after slowing down on the approach
    safety = status(daemon)["safety"]
    # held at the stop zone's edge: the approach stops the last creeping centimetres short
    assert safety["zone"] in ("stop", "slowdown") and safety["nearest_m"] is not None
    assert safety["nearest_m"] < STOP_MARGIN + 0.1
    assert safety["scan_age_s"] is not None and safety["scan_age_s"] < 0.5
    code, metrics = daemon.get("/api/sim/metrics")
    assert code == 200 and metrics["collisions"] == 0
    code, text = daemon.get("/metrics")
    assert code == 200 and 'arbiterd_collision_monitor_actions_total{action="stop"}' in text

    assert daemon.post("/api/sim/reset", {})[0] == 200
    code, body = daemon.post("/api/autonomy", {"mode": "wander"})
    assert code == 200 and body["mode"] == "wander", body
    start = daemon.get("/api/sim/metrics")[1]["path_length_m"]
    metrics = watch_for(daemon, 20.0)  # the behaviour on its own for 20 s of real time
    assert metrics["path_length_m"] - start > 2.0, metrics  # it did get around
    code, autonomy = daemon.get("/api/autonomy")
    assert autonomy["mode"] == "wander", autonomy  # it did not switch itself off
    # a stale scan or a stall wait on a loaded machine stops it for a moment: it moves on
    wait_for(lambda: daemon.get("/api/autonomy")[1]["state"] != "STOPPED",
             lambda: f"wander to leave STOPPED: {daemon.get('/api/autonomy')[1]}", within_s=10.0)
    assert "collision monitor:" in daemon.log()  # changes of action are logged


def drive_at_the_wall(daemon: DaemonSubprocess, seconds: float) -> tuple[float, set[str]]:
    """A teleop holding 1 m/s toward the wall at ~20 Hz; the closest the footprint came to
    the wall (ground truth) and the safety actions /api/status showed."""
    closest, actions = float("inf"), set()
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        code, body = daemon.post("/api/cmd_vel", {"linear": {"x": 1.0}})
        assert code == 200 and body["accepted"], body
        actions.add(body["safety"])  # what the monitor did to this very command
        now = status(daemon)
        closest = min(closest, WALL_X - now["ground_truth"]["x"] - FOOTPRINT)
        actions.add(now["safety"]["action"])
        time.sleep(0.05)
    return closest, actions


def watch_for(daemon: DaemonSubprocess, seconds: float) -> dict[str, Any]:
    """Poll /api/sim/metrics for ``seconds``, failing at the first collision; the last."""
    deadline = time.monotonic() + seconds
    while True:
        code, metrics = daemon.get("/api/sim/metrics")
        assert code == 200 and metrics["collisions"] == 0, metrics
        if time.monotonic() >= deadline:
            return metrics  # type: ignore[no-any-return]
        time.sleep(0.25)
