# Odometry that drifts like a real base: calibration errors, slip and lidar dropouts against the
# ground truth, in the stepped world and in `arbiterd simulate`'s lockstep runner.
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from daemon.commands import parse_twist
from daemon.config import load_config
from daemon.lockstep.runner import Lockstep
from daemon.lockstep.script import Step
from sim.noise import Noise, NoiseConfig
from sim.settings import SimConfig, SimConfigError
from sim.stepper import SimWorld, heading_error
from sim.world import World, arena_walls
from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.wait import wait_for

OPEN = World(arena_walls(40.0, 40.0), ())


def world_with(**sim: Any) -> SimWorld:
    """An exact (noise-free unless asked) world in a 40 m arena with the default robot."""
    section: dict[str, Any] = {"noise": False, **sim}
    return SimWorld(SimConfig.from_section(section), world=OPEN)


def odometry_wheels(world: SimWorld) -> tuple[float, float]:
    """Each wheel's travel (m) as odometry sees it: encoder turns x the configured radius."""
    left, right = world.motors.positions()
    return left * world.configured.wheel_radius, right * world.configured.wheel_radius


def drive_by_odometry(world: SimWorld, v: float, w: float, done: Any) -> None:
    """Command the twist until ``done(left_m, right_m)`` on the odometry, then stop."""
    world.command_twist(v, w)
    for _ in range(100_000):
        if done(*odometry_wheels(world)):
            break
        world.step()
    world.command_twist(0.0, 0.0)
    world.advance(1.0)


@pytest.mark.parametrize("error", [0.02, -0.03])
def test_radius_error_makes_a_5_m_odometry_drive_off_by_that_fraction(error: float) -> None:
    world = world_with(wheel_radius_error=error)
    drive_by_odometry(world, 0.5, 0.0, lambda left, right: (left + right) / 2 >= 5.0)
    odometry = sum(odometry_wheels(world)) / 2
    truth = world.ground_truth()
    assert odometry == pytest.approx(5.0, abs=0.05)  # the motors lag: it coasts ~2.5 cm
    assert truth.x - odometry == pytest.approx(odometry * error, abs=1e-6)  # ~0.1 m at 2 %
    assert truth.y == pytest.approx(0.0, abs=1e-9) and truth.theta == pytest.approx(0.0)


def test_separation_error_makes_turns_drift_in_heading_but_not_straights() -> None:
    world = world_with(wheel_separation_error=0.03)
    configured = world.configured.wheel_separation

    def one_turn(left: float, right: float) -> bool:
        return (right - left) / configured >= 2 * math.pi
    drive_by_odometry(world, 0.0, 1.0, one_turn)
    left, right = odometry_wheels(world)
    odometry_heading = (right - left) / configured
    expected = odometry_heading / 1.03  # the true wheels are farther apart: it turns less
    assert heading_error(world.ground_truth().theta, expected) < 1e-6
    assert math.degrees(odometry_heading - expected) == pytest.approx(10.5, abs=0.2)
    straight = world_with(wheel_separation_error=0.03)
    drive_by_odometry(straight, 0.5, 0.0, lambda lm, rm: (lm + rm) / 2 >= 3.0)
    assert straight.ground_truth().theta == pytest.approx(0.0, abs=1e-12)


def test_zero_errors_keep_the_configured_geometry() -> None:
    world = SimWorld(SimConfig.from_section(), wheel_radius=0.04, wheel_separation=0.25,
                     world=OPEN)
    assert world.geometry == world.configured
    tuned = SimWorld(SimConfig.from_section({"wheel_radius_error": 0.1,
                                             "wheel_separation_error": -0.1}),
                     wheel_radius=0.04, wheel_separation=0.25, world=OPEN)
    assert tuned.geometry.wheel_radius == pytest.approx(0.044)
    assert tuned.geometry.wheel_separation == pytest.approx(0.225)
    assert tuned.configured.wheel_radius == 0.04


def test_dropouts_remove_that_fraction_of_returns_seeded() -> None:
    ranges = np.full(360, 3.0)
    ranges[::4] = np.inf  # 90 rays with no return to begin with
    noise = Noise(NoiseConfig(lidar_sigma=0.0, lidar_dropout=0.1, seed=7))
    scans = np.array([noise.lidar(ranges) for _ in range(200)])
    returns = np.isfinite(ranges).sum() * len(scans)
    assert np.isfinite(scans).sum() / returns == pytest.approx(0.9, abs=0.01)
    assert np.isinf(scans[:, ::4]).all()  # a ray without a return never gets one
    again = Noise(NoiseConfig(lidar_sigma=0.0, lidar_dropout=0.1, seed=7))
    assert np.array_equal(np.array([again.lidar(ranges) for _ in range(200)]), scans)
    other = Noise(NoiseConfig(lidar_sigma=0.0, lidar_dropout=0.1, seed=8))
    assert not np.array_equal(other.lidar(ranges), scans[0])


def test_dropouts_leave_the_range_noise_and_encoders_as_they_were() -> None:
    ranges = np.full(360, 3.0)
    plain, dropping = Noise(NoiseConfig(seed=3)), Noise(NoiseConfig(seed=3, lidar_dropout=0.3))
    a, b = plain.lidar(ranges), dropping.lidar(ranges)
    kept = np.isfinite(b)
    assert 0 < kept.sum() < len(b) and np.array_equal(a[kept], b[kept])
    assert plain.encoder_offsets() == dropping.encoder_offsets()
    off = Noise(NoiseConfig(enabled=False, lidar_dropout=0.5))
    assert off.lidar(ranges) is ranges  # noise = false switches dropouts off too


def test_the_world_scan_drops_returns() -> None:
    world = SimWorld(SimConfig.from_section({"lidar_dropout": 0.25, "lidar_noise": 0.0}),
                     world=World(arena_walls(8.0, 8.0), ()))
    kept = np.mean([np.isfinite(world.scan()).mean() for _ in range(100)])
    assert kept == pytest.approx(0.75, abs=0.02)


@pytest.mark.parametrize(("key", "value", "words"), [
    ("lidar_dropout", 1.0, "must be < 1"),
    ("lidar_dropout", -0.1, ">= 0"),
    ("wheel_radius_error", 0.6, "<= 0.5"),
    ("wheel_separation_error", -0.7, ">= -0.5"),
    ("wheel_radius_error", "2%", "expected"),
])
def test_bad_values_are_refused_naming_the_key(key: str, value: Any, words: str) -> None:
    with pytest.raises(SimConfigError, match=rf"\[sim\] {key}: .*{words}"):
        SimConfig.from_section({key: value})


# -- the same drift in `arbiterd simulate` (the lockstep runner and the daemon's odometry) -----

def lockstep(tmp_path: Path, sim: Mapping[str, Any], steps: list[Step],
             robot: Mapping[str, Any]) -> Lockstep:
    world = tmp_path / "open.toml"
    world.write_text("[arena]\nwidth = 30.0\nheight = 30.0\n")
    config = load_config(None, sim=True, env={})
    config.update("sim", {"world_file": str(world), **sim})
    config.update("robot", dict(robot))
    return Lockstep(config, script=steps)


async def drive(tmp_path: Path, sim: Mapping[str, Any], v: float, w: float, seconds: float,
                robot: Mapping[str, Any] | None = None) -> tuple[Any, Any]:
    twist = {"linear": {"x": v}, "angular": {"z": w}}
    steps = [Step(0.0, "cmd_vel", parse_twist(twist)), Step(seconds, "stop", True)]
    runner = lockstep(tmp_path, sim, steps, robot or {})
    await runner.run(seconds + 2.0)
    return runner.control.odometry.pose, runner.world.ground_truth()


async def test_lockstep_radius_error_drifts_two_percent_of_the_distance(tmp_path: Path) -> None:
    odom, truth = await drive(tmp_path, {"noise": False, "wheel_radius_error": 0.02}, 0.5, 0.0,
                              10.0)
    assert odom.x == pytest.approx(5.0, abs=0.3)  # commanded 0.5 m/s for 10 s, with ramps
    assert truth.x - odom.x == pytest.approx(0.02 * odom.x, abs=0.002)  # ~0.1 m


async def test_lockstep_separation_error_drifts_the_heading_on_turns(tmp_path: Path) -> None:
    odom, truth = await drive(tmp_path, {"noise": False, "wheel_separation_error": 0.05},
                              0.0, 0.5, 3.0)
    assert odom.theta > 1.0
    assert heading_error(truth.theta, odom.theta / 1.05) < 1e-3


async def test_the_robot_calibration_multipliers_cancel_the_drift(tmp_path: Path) -> None:
    sim = {"noise": False, "wheel_radius_error": 0.02, "wheel_separation_error": 0.03}
    robot = {"left_wheel_radius_multiplier": 1.02, "right_wheel_radius_multiplier": 1.02,
             "wheel_separation_multiplier": 1.03}
    odom, truth = await drive(tmp_path, sim, 0.4, 0.5, 6.0, robot)
    assert math.hypot(odom.x - truth.x, odom.y - truth.y) < 1e-3
    assert math.hypot(odom.x, odom.y) > 1.0 and odom.theta > 2.0  # it did drive an arc
    assert heading_error(odom.theta, truth.theta) < 1e-3


async def test_lockstep_drift_is_seeded_and_reproducible(tmp_path: Path) -> None:
    sim = {"seed": 4, "wheel_slip": 0.02, "wheel_radius_error": 0.02,
           "wheel_separation_error": -0.02, "lidar_dropout": 0.1}
    first = await drive(tmp_path, sim, 0.4, 0.3, 6.0)
    again = await drive(tmp_path, sim, 0.4, 0.3, 6.0)
    other = await drive(tmp_path, {**sim, "seed": 5}, 0.4, 0.3, 6.0)
    assert first == again
    assert other[0] != first[0]  # another seed, other encoder noise


# -- the same drift in `arbiterd run --sim` (the real driver through the emulated Arduino) ------

def test_run_sim_encoders_count_config_geometry_while_the_robot_moves_true(
        tmp_path: Path) -> None:
    toml = ('[sim]\ndriver = "serial"\nnoise = false\nwheel_radius_error = 0.05\n'
            'wheel_separation_error = 0.10\n')
    with DaemonSubprocess(tmp_path, toml, args=("--sim",), use_mock_log=False) as daemon:
        drive_until(daemon, lambda s: {"linear": {"x": approach(1.0 - s["pose"]["x"], 0.4)}},
                    lambda s: s["pose"]["x"] >= 1.0 - 0.004)
        wait_for(lambda: at_rest(daemon), "the robot to stop after 1 m", within_s=5)
        moved = status(daemon)
        assert moved["ground_truth"]["x"] - moved["pose"]["x"] == pytest.approx(
            0.05 * moved["pose"]["x"], abs=0.01)  # the true wheels are 5 % larger
        drive_until(daemon, lambda s: {"angular": {"z": approach(
            math.pi / 2 - s["pose"]["theta"], 0.6)}},
            lambda s: s["pose"]["theta"] >= math.pi / 2 - 0.005)
        wait_for(lambda: at_rest(daemon), "the robot to stop after the turn", within_s=5)
        turned = status(daemon)
        odom, truth = turned["pose"]["theta"], turned["ground_truth"]["theta"]
        assert math.degrees(heading_error(truth, odom * 1.05 / 1.10)) < 1.0, (odom, truth)
        assert math.degrees(odom - truth) > 3.0  # ~4 degrees short of what odometry says


def status(daemon: DaemonSubprocess) -> dict[str, Any]:
    code, body = daemon.get("/api/status")
    assert code == 200, body
    return body


def approach(remaining: float, fastest: float) -> float:
    """Full speed far from the goal, slowing down near it."""
    return max(0.04, min(fastest, 1.5 * remaining))


def drive_until(daemon: DaemonSubprocess, command: Callable[[dict[str, Any]], dict[str, Any]],
                done: Callable[[dict[str, Any]], bool]) -> None:
    """Send ``command(status)`` at ~20 Hz until ``done(status)``, then command zero."""

    def done_else_command() -> bool:
        now = status(daemon)
        if done(now):
            return True
        assert daemon.post("/api/cmd_vel", command(now))[0] == 200
        return False

    wait_for(done_else_command, "the goal", within_s=20, interval_s=0.05)
    assert daemon.post("/api/cmd_vel", {})[0] == 200


def at_rest(daemon: DaemonSubprocess) -> bool:
    truth = status(daemon)["ground_truth"]
    return abs(truth["v"]) < 1e-3 and abs(truth["w"]) < 1e-3


async def test_the_mock_driver_in_the_simulator_counts_the_worlds_wheel_turns() -> None:
    # run --sim with the mock driver: its encoders read the world's wheels, so odometry
    # counts what the wheels truly turned (motor lag, a world thread that fell behind and
    # skipped ahead), not the commands integrated over the daemon's clock
    from daemon.components.sim.component import SimRuntime
    from drivers.mock import MockDriver

    config = load_config(None, sim=True, env={})
    config.update("sim", {"driver": "mock"})
    runtime = SimRuntime(config)
    driver = MockDriver({}, max_wheel_speed=20.0)
    runtime.attach(driver)
    await driver.open()
    try:
        await driver.set_wheel_speeds(5.0, 5.0)
        runtime.world.advance(1.0)
        first = driver.read_encoders()
        assert first is not None
        assert (first.left_rad, first.right_rad) == runtime.motors.encoder_positions()
        assert 0.0 < first.left_rad < 5.0  # the motor's lag: less than the command's 5 rad
        # the world is not stepped (its thread fell behind): the wheels did not turn
        again = driver.read_encoders()
        assert again is not None and again.left_rad == first.left_rad
    finally:
        await driver.close()
        await runtime.stop()
