# The simulated robot end to end, once per registered driver: `arbiterd run --sim` as a subprocess,
# driven over HTTP like a user's script: 1 m forward at 0.5 m/s, 90° in place, stop.
from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers import DRIVERS
from sim.raycast import RayCaster
from sim.settings import SimConfig
from sim.stepper import build_world
from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.wait import wait_for

LINEAR, ANGULAR = 0.5, 0.6


def status(daemon: DaemonSubprocess) -> dict[str, Any]:
    code, body = daemon.get("/api/status")
    assert code == 200, body
    return body  # type: ignore[no-any-return]


def drive_until(daemon: DaemonSubprocess, command: Callable[[dict[str, Any]], dict[str, Any]],
                done: Callable[[dict[str, Any]], bool], within_s: float = 20.0) -> None:
    """Send ``command(status)`` at ~20 Hz until ``done(status)``, then command zero."""
    now: dict[str, Any] = {}

    def done_else_command() -> bool:
        nonlocal now
        if done(now := status(daemon)):
            return True
        code, body = daemon.post("/api/cmd_vel", command(now))
        assert code == 200, body
        return False

    wait_for(done_else_command, lambda: f"the goal; last status: {now}", within_s=within_s,
             interval_s=0.05)
    assert daemon.post("/api/cmd_vel", {})[0] == 200


def approach(remaining: float, fastest: float, gain: float, slowest: float) -> float:
    """Proportional approach: full speed far away, slowing down near the goal."""
    return max(slowest, min(fastest, gain * remaining))


def at_rest(daemon: DaemonSubprocess) -> bool:
    truth = status(daemon)["ground_truth"]
    return abs(truth["v"]) < 1e-3 and abs(truth["w"]) < 1e-3


def heading_error(a: float, b: float) -> float:
    return abs(math.atan2(math.sin(a - b), math.cos(a - b)))


@pytest.fixture(params=sorted(DRIVERS))
def sim_daemon(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[DaemonSubprocess]:
    toml = f'[sim]\ndriver = "{request.param}"\n'
    with DaemonSubprocess(tmp_path, toml, args=("--sim",), use_mock_log=False) as daemon:
        yield daemon


def test_drive_one_metre_turn_ninety_degrees(sim_daemon: DaemonSubprocess) -> None:
    daemon = sim_daemon
    code, health = daemon.get("/api/health")
    assert code == 200 and health["mode"] == "sim", health
    x0 = status(daemon)["pose"]["x"]

    def forward(s: dict[str, Any]) -> dict[str, Any]:
        return {"linear": {"x": approach(1.0 - (s["pose"]["x"] - x0), LINEAR, 1.5, 0.04)}}

    drive_until(daemon, forward, lambda s: s["pose"]["x"] - x0 >= 1.0 - 0.004)
    wait_for(lambda: at_rest(daemon), "the robot to stop after 1 m", within_s=5)

    def turn(s: dict[str, Any]) -> dict[str, Any]:
        return {"angular": {"z": approach(math.pi / 2 - s["pose"]["theta"], ANGULAR, 2.0, 0.08)}}

    drive_until(daemon, turn, lambda s: s["pose"]["theta"] >= math.pi / 2 - 0.005)
    wait_for(lambda: at_rest(daemon), "the robot to stop after the turn", within_s=5)

    final = status(daemon)
    truth, odom = final["ground_truth"], final["pose"]
    assert math.hypot(truth["x"] - 1.0, truth["y"]) <= 0.05, truth
    assert math.degrees(heading_error(truth["theta"], math.pi / 2)) <= 3.0, truth
    # odometry (the daemon's own estimate through the real driver) agrees with the truth
    assert math.hypot(odom["x"] - truth["x"], odom["y"] - truth["y"]) <= 0.05, (odom, truth)
    assert math.degrees(heading_error(odom["theta"], truth["theta"])) <= 3.0
    assert truth["collisions"] == 0
    code, metrics = daemon.get("/api/sim/metrics")
    assert code == 200 and metrics["path_length_m"] == pytest.approx(1.0, abs=0.1), metrics
    check_scan_matches_world(daemon, truth)
    code, health = daemon.get("/api/health")  # no false wheel-mismatch stop on the way
    assert code == 200 and health["components"]["control"]["wheel_guard"]["trips"] == 0


def latest_scan_after(daemon: DaemonSubprocess, stamp: float) -> dict[str, Any]:
    def fresh() -> dict[str, Any] | None:
        code, scan = daemon.get("/api/scan")
        return scan if code == 200 and scan["stamp"] > stamp else None

    result: dict[str, Any] = wait_for(fresh, "a revolution taken at rest", within_s=5)
    return result


def check_scan_matches_world(daemon: DaemonSubprocess, truth: dict[str, Any]) -> None:
    """The scan read through the emulated RPLIDAR's bytes equals a ray cast of the world from
    the true pose, within the lidar noise (sigma 0.02 m) and binning to 1° rays."""
    scan = latest_scan_after(daemon, time.time() + 0.05)
    ranges = np.array([np.inf if r is None else r for r in scan["ranges"]])
    angles = scan["angle_min"] + np.arange(ranges.size) * scan["angle_increment"]
    world = build_world(SimConfig.from_section({"seed": 1}))
    expected = RayCaster(world, angles, 0.1, 10.0).cast(truth["x"], truth["y"], truth["theta"])
    ahead = int(np.argmin(np.abs(angles)))
    assert abs(angles[ahead]) <= math.radians(0.5)
    assert ranges[ahead] == pytest.approx(expected[ahead], abs=0.1), (ranges[ahead],
                                                                      expected[ahead])
    both = np.isfinite(ranges) & np.isfinite(expected)
    assert both.sum() > 250  # the arena's corners are beyond the 10 m range
    assert np.mean(np.isfinite(ranges) == np.isfinite(expected)) > 0.95
    assert float(np.median(np.abs(ranges[both] - expected[both]))) < 0.03


def test_driving_into_an_obstacle_counts_a_collision(tmp_path: Path) -> None:
    # the collision monitor would stop the robot short of it (tests/test_simulate.py)
    toml = ('[sim]\ndriver = "serial"\nnoise = false\n'
            '[collision_monitor]\nenabled = false\n')
    with DaemonSubprocess(tmp_path, toml, args=("--sim",), use_mock_log=False) as daemon:
        sim = SimConfig.from_section({"seed": 1, "noise": False})
        world = build_world(sim)
        # face the nearest obstacle straight ahead, 1.5 m clear of it
        target = min(world.circles, key=lambda c: math.hypot(c.x, c.y))
        bearing = math.atan2(target.y, target.x)
        gap = math.hypot(target.x, target.y) - target.r - sim.footprint_radius
        x, y = target.x - (target.r + sim.footprint_radius + 1.5) * math.cos(bearing), \
            target.y - (target.r + sim.footprint_radius + 1.5) * math.sin(bearing)
        assert gap > 0
        code, _ = daemon.post("/api/sim/reset", {"x": x, "y": y, "theta": bearing})
        assert code == 200
        drive_until(daemon, lambda s: {"linear": {"x": 1.0}},
                    lambda s: s["ground_truth"]["collisions"] >= 1, within_s=10)
        truth = status(daemon)["ground_truth"]
        clearance = math.hypot(truth["x"] - target.x, truth["y"] - target.y)
        assert clearance >= target.r + sim.footprint_radius - 1e-3, "passed through"
        caster = RayCaster(world, np.array([0.0]), 0.0, 100.0)
        # touching: the obstacle is one footprint radius ahead of the robot's centre
        ahead = caster.cast(truth["x"], truth["y"], truth["theta"])[0]
        assert ahead == pytest.approx(sim.footprint_radius, abs=0.02)
        code, metrics = daemon.get("/api/sim/metrics")
        assert metrics["collisions"] == 1
