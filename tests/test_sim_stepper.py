# Tests of SimWorld: the scenario drive, lidar conventions, reset, real-time stepping, settings.
from __future__ import annotations

import math
import threading
from pathlib import Path

import numpy as np
import pytest

from base.options import defaults
from sim.motor_model import MotorPair
from sim.physics import make_motors
from sim.settings import SimConfig, SimConfigError, SimSettings
from sim.stepper import SimWorld, heading_error
from sim.world import Circle, Pose, World, arena_walls

EXACT = SimConfig.from_section({"noise": False})


def _ramp_drive(world: SimWorld, v: float, w: float, seconds: float) -> None:
    """Hold a twist for ``seconds``, then stop and let the motors settle."""
    world.command_twist(v, w)
    world.advance(seconds)
    world.command_twist(0.0, 0.0)
    world.advance(1.0)


def test_scenario_drive_1_m_turn_90_and_stop_lands_on_the_ideal_pose() -> None:
    world = SimWorld(SimConfig.from_section({"seed": 1}))  # default noise on
    _ramp_drive(world, 0.5, 0.0, 2.0)
    _ramp_drive(world, 0.0, math.pi / 4, 2.0)
    truth = world.ground_truth()
    assert math.hypot(truth.x - 1.0, truth.y) < 0.05
    assert heading_error(truth.theta, math.pi / 2) < math.radians(3)
    # odometry from the emulated encoders agrees with the truth within the noise
    left, right = (p * world.geometry.wheel_radius for p in world.motors.positions())
    sigma = world.config.noise.odom_sigma
    assert abs((left + right) / 2 - 1.0) < 6 * sigma  # the forward leg
    turn = (right - left) / world.geometry.wheel_separation
    assert abs(turn - truth.theta) < 6 * sigma * math.sqrt(2) / world.geometry.wheel_separation
    # the scan straight ahead (now facing +y) is the ray-cast distance, within the noise
    ahead = world.scan()[0]
    exact = world.exact_range(0.0)
    assert abs(ahead - exact) < 6 * world.config.noise.lidar_sigma


def test_exact_world_drives_exactly() -> None:
    world = SimWorld(EXACT)
    _ramp_drive(world, 0.5, 0.0, 2.0)
    assert world.ground_truth().x == pytest.approx(1.0, abs=1e-6)
    assert world.scan()[0] == world.exact_range(0.0)


def test_scan_ranges_use_the_rplidar_clockwise_convention() -> None:
    world = SimWorld(EXACT, world=World(arena_walls(16, 16), (Circle(0.0, 3.0, 0.5),)))
    cw = np.radians([0.0, 90.0, 180.0, 270.0])  # ahead, right, behind, left
    ranges = world.scan_ranges(cw, 0.0)
    assert ranges.tolist() == pytest.approx([8.0, 8.0, 8.0, 2.5])
    ccw = world.scan()  # ROS order: index 90 is the left
    assert ccw[90] == pytest.approx(2.5) and ccw[270] == pytest.approx(8.0)
    assert world.scan_ranges(np.radians([270.0]), 1.0)[0] == pytest.approx(2.5)  # re-cast


def test_internal_scans_follow_the_lidar_rate() -> None:
    world = SimWorld(EXACT, internal_scans=True)
    seen = []
    for _ in range(50):
        world.step()
        seen.append(world.latest_scan_time)
    assert sorted(set(seen)) == pytest.approx([0.02, 0.12, 0.22, 0.32, 0.42, 0.52, 0.62, 0.72,
                                               0.82, 0.92])
    assert world.latest_scan is not None and len(world.latest_scan) == 360


def test_reset_teleports_and_starts_a_new_metrics_run() -> None:
    world = SimWorld(EXACT)
    _ramp_drive(world, 0.5, 0.0, 1.0)
    truth = world.reset(Pose(-2.0, 3.0, 1.0))
    assert (truth.x, truth.y, truth.theta) == (-2.0, 3.0, 1.0)
    assert world.metrics_summary()["run"] == 2
    assert world.metrics_summary()["path_length_m"] == 0.0
    with pytest.raises(ValueError, match="footprint on an obstacle or wall"):
        world.reset(Pose(7.95, 0.0, 0.0))
    truth = world.reset()
    assert (truth.x, truth.y, truth.theta) == (0.0, 0.0, 0.0)
    assert truth.to_json()["collisions"] == 0


def test_real_time_thread_drives_the_shared_motors() -> None:
    world = SimWorld(EXACT)
    world.start(speed=4.0)
    try:
        # an emulator on another thread commands the same MotorPair
        threading.Thread(target=world.motors.set_targets, args=(10.0, 10.0)).start()
        assert world.wait_until(1.0, timeout=10.0)
        assert world.running and world.health()["running"]
    finally:
        world.stop()
    assert not world.running
    steps = world.steps
    assert world.ground_truth().x > 0.1
    assert not world.wait_until(world.time + 1.0, timeout=0.05)  # stopped: time stands still
    assert world.steps == steps
    world.stop()  # idempotent
    world.close()


def test_a_failing_step_is_reported_in_health(monkeypatch: pytest.MonkeyPatch) -> None:
    world = SimWorld(EXACT)

    def broken(dt: float) -> None:
        raise RuntimeError("boom")

    monkeypatch.setattr(world.physics, "step", broken)
    world.start()
    deadline_ok = world.wait_until(1.0, timeout=0.5)
    world.stop()
    assert not deadline_ok
    health = world.health()
    assert health["status"] == "error" and "boom" in str(health["error"])


def test_motors_must_be_stepped_by_the_world() -> None:
    with pytest.raises(ValueError, match="clock=None"):
        SimWorld(EXACT, motors=MotorPair())
    shared = make_motors()
    assert SimWorld(EXACT, motors=shared).motors is shared


def test_sim_options_defaults_match_the_design() -> None:
    values = defaults(SimSettings.OPTIONS)
    assert values["driver"] == "serial" and values["seed"] == 1
    assert SimSettings.OPTIONS["driver"].choices is not None
    assert set(SimSettings.OPTIONS["driver"].choices) == {"mock", "l298n", "pigpio",
                                                          "serial", "odrive_can"}
    config = SimConfig.from_section({})
    assert (config.arena_size, config.obstacles, config.lidar_rays) == (16.0, 8, 360)
    assert (config.range_min, config.range_max, config.lidar_rate) == (0.1, 10.0, 10.0)
    assert (config.physics_rate, config.noise.lidar_sigma, config.noise.odom_sigma) == (
        50.0, 0.02, 0.005)
    for key, option in SimSettings.OPTIONS.items():
        assert option.validate(option.default)[1] is None, key
    assert config.exact().noise.enabled is False


@pytest.mark.parametrize(("section", "message"), [
    ({"driver": "roomba"}, r"\[sim\] driver: must be one of"),
    ({"sede": 1}, r"\[sim\] sede: unknown key"),
    ({"lidar_noise": -0.1}, r"\[sim\] lidar_noise: must be >= 0"),
    ({"start_pose": [1.0, 2.0]}, r"\[sim\] start_pose: expected a list of 3 items"),
    ({"range_min": 5.0, "range_max": 2.0}, r"\[sim\] range_min \(5.0\) must be < range_max"),
    ({"obstacle_radius_min": 0.9}, r"\[sim\] obstacle_radius_min \(0.9\) must be <="),
    ({"physics_rate": True}, r"\[sim\] physics_rate: expected a number"),
])
def test_bad_sim_settings_name_the_key(section: dict[str, object], message: str) -> None:
    with pytest.raises(SimConfigError, match=message):
        SimConfig.from_section(section)


def test_world_file_setting_loads_the_file(tmp_path: Path) -> None:
    path = tmp_path / "corridor.json"
    path.write_text('{"arena": {"width": 10, "height": 2}, "start": {"x": -4, "y": 0}}')
    world = SimWorld(SimConfig.from_section({"world_file": str(path), "noise": False}))
    assert world.ground_truth().x == -4.0
    assert world.scan()[0] == pytest.approx(9.0)
    assert world.scan()[90] == pytest.approx(1.0)


def test_builds_from_the_daemons_validated_sections(tmp_path: Path) -> None:
    from daemon.config import load_config

    path = tmp_path / "arbiterd.toml"
    path.write_text('[robot]\nwheel_radius = 0.04\nwheel_separation = 0.25\n'
                    '[sim]\nseed = 3\nnoise = false\nstart_pose = [1.0, -1.0, 0.5]\n')
    config = load_config(path, sim=True, env={})
    world = SimWorld.from_sections(config["sim"], config["robot"])
    assert (world.geometry.wheel_radius, world.geometry.wheel_separation) == (0.04, 0.25)
    assert world.config.seed == 3 and not world.config.noise.enabled
    truth = world.ground_truth()
    assert (truth.x, truth.y, truth.theta) == (1.0, -1.0, 0.5)


def test_unwritable_metrics_csv_names_the_key(tmp_path: Path) -> None:
    config = SimConfig.from_section({"metrics_csv": str(tmp_path / "missing" / "m.csv")})
    with pytest.raises(SimConfigError, match=r"\[sim\] metrics_csv: cannot write"):
        SimWorld(config)
