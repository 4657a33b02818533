# Tests of the diff-drive physics: exact motion, collisions counted, no tunnelling.
from __future__ import annotations

import math

import numpy as np
import pytest

from sim.motor_model import MotorPair
from sim.noise import Noise, NoiseConfig
from sim.physics import DiffDrivePhysics, RobotGeometry, first_contact, make_motors
from sim.world import Circle, Pose, Segment, World, arena_walls, generated_world

GEOMETRY = RobotGeometry(wheel_radius=0.05, wheel_separation=0.30, footprint_radius=0.2)
DT = 0.02


def _physics(world: World, noise: NoiseConfig | None = None,
             wheel_sign: int = 1) -> tuple[DiffDrivePhysics, MotorPair]:
    motors = make_motors()
    noise_model = Noise(noise) if noise else None
    return DiffDrivePhysics(world, motors, GEOMETRY, noise_model, wheel_sign=wheel_sign), motors


def _run(physics: DiffDrivePhysics, seconds: float) -> None:
    for _ in range(round(seconds / DT)):
        physics.step(DT)


def test_straight_drive_is_exact_without_noise() -> None:
    physics, motors = _physics(World(arena_walls(16, 16), ()))
    motors.set_targets(10.0, 10.0)  # 0.5 m/s
    _run(physics, 2.0)
    motors.set_targets(0.0, 0.0)
    _run(physics, 1.5)  # the first-order lag gives back what it held
    state = physics.state
    assert state.x == pytest.approx(1.0, abs=1e-6)
    assert state.y == 0.0 and state.theta == 0.0
    assert motors.positions() == pytest.approx((20.0, 20.0), abs=1e-6)
    assert state.collisions == 0


def test_turn_in_place_is_exact_without_noise() -> None:
    physics, motors = _physics(World(arena_walls(16, 16), ()))
    wheel = math.pi / 2 * GEOMETRY.wheel_separation / 2 / GEOMETRY.wheel_radius / 1.5
    motors.set_targets(-wheel, wheel)
    _run(physics, 1.5)
    motors.set_targets(0.0, 0.0)
    _run(physics, 1.5)
    assert physics.state.theta == pytest.approx(math.pi / 2, abs=1e-6)
    assert (physics.state.x, physics.state.y) == pytest.approx((0.0, 0.0), abs=1e-12)


def test_arc_follows_the_circle() -> None:
    physics, motors = _physics(World(arena_walls(40, 40), ()))
    motors.left.speed_rad_s = motors.left.target_rad_s = 8.0  # already at speed: exact arc
    motors.right.speed_rad_s = motors.right.target_rad_s = 12.0
    _run(physics, 1.0)
    v, w = 0.5, (0.6 - 0.4) / 0.30
    radius = v / w
    assert physics.state.theta == pytest.approx(w * 1.0)
    assert physics.state.x == pytest.approx(radius * math.sin(w), abs=1e-9)
    assert physics.state.y == pytest.approx(radius * (1 - math.cos(w)), abs=1e-9)


def test_collision_at_1_m_s_is_counted_once_and_the_robot_stops_at_the_obstacle() -> None:
    physics, motors = _physics(World(arena_walls(16, 16), (Circle(3.0, 0.0, 0.5),)))
    motors.set_targets(20.0, 20.0)  # 1 m/s
    stop_at = 3.0 - 0.5 - GEOMETRY.footprint_radius
    for _ in range(250):  # 5 s: reaches it after ~2.3 s, then keeps pushing
        physics.step(DT)
        assert physics.state.x <= stop_at
    assert physics.state.x == pytest.approx(stop_at, abs=1e-5)
    assert physics.state.collisions == 1
    assert physics.state.in_contact and physics.state.v == pytest.approx(0.0, abs=1e-6)
    assert motors.positions()[0] * GEOMETRY.wheel_radius > 4.5  # the wheels spun on
    motors.set_targets(-20.0, -20.0)  # back off: allowed, contact ends
    _run(physics, 0.5)
    assert physics.state.x < stop_at - 0.2 and not physics.state.in_contact
    motors.set_targets(20.0, 20.0)  # and again: a second collision
    _run(physics, 2.0)
    assert physics.state.collisions == 2
    assert physics.state.x == pytest.approx(stop_at, abs=1e-5)


@pytest.mark.parametrize("dt", [0.02, 0.2, 0.5])
def test_no_tunnelling_through_a_thin_wall_or_a_small_post_at_2_m_s(dt: float) -> None:
    thin = World((Segment(1.0, -1.0, 1.0, 1.0),), ())
    post = World((), (Circle(1.0, 0.0, 0.02),))
    for world, stop_at in ((thin, 0.8), (post, 0.78)):
        physics, motors = _physics(world)
        motors.set_targets(40.0, 40.0)  # 2 m/s: up to 1 m per step at dt=0.5
        for _ in range(round(3.0 / dt)):
            physics.step(dt)
            assert physics.state.x <= stop_at
        assert physics.state.x == pytest.approx(stop_at, abs=1e-5)
        assert physics.state.collisions == 1


def test_glancing_contact_then_turning_away_frees_the_robot() -> None:
    physics, motors = _physics(World(arena_walls(4, 4), ()))
    physics.place(Pose(0.0, 0.0, math.radians(60)))
    motors.set_targets(20.0, 20.0)
    _run(physics, 4.0)
    assert physics.state.collisions == 1
    assert physics.state.y == pytest.approx(2.0 - 0.2, abs=1e-5)  # stopped by the top wall
    motors.set_targets(10.0, -10.0)  # turning in place (clockwise) is never blocked
    _run(physics, 0.6)
    assert physics.state.theta < 0  # now heading down and away
    motors.set_targets(20.0, 20.0)
    _run(physics, 0.3)
    assert physics.state.y < 1.7 and not physics.state.in_contact


def test_the_footprint_never_enters_an_obstacle_while_wandering() -> None:
    world = generated_world(5)
    physics, motors = _physics(world, NoiseConfig(seed=5, wheel_slip=0.05))
    rng = np.random.default_rng(5)
    for step in range(6000):
        if step % 150 == 0:
            forward = rng.uniform(-20.0, 40.0)
            turn = rng.uniform(-3.0, 3.0)
            motors.set_targets(forward - turn, forward + turn)
        physics.step(DT)
        s = physics.state
        assert world.clearance(s.x, s.y) >= GEOMETRY.footprint_radius - 1e-9
    assert physics.state.collisions > 0  # the wander did hit things


def test_wheel_slip_shortens_the_true_motion() -> None:
    physics, motors = _physics(World(arena_walls(16, 16), ()),
                               NoiseConfig(lidar_sigma=0.0, odom_sigma=0.0, wheel_slip=0.1))
    motors.set_targets(10.0, 10.0)
    _run(physics, 2.0)
    motors.set_targets(0.0, 0.0)
    _run(physics, 1.5)
    assert physics.state.x == pytest.approx(0.9, abs=1e-6)
    assert motors.positions()[0] * GEOMETRY.wheel_radius == pytest.approx(1.0, abs=1e-6)


def test_mirrored_wheels_drive_forward_with_negative_speeds() -> None:
    physics, motors = _physics(World(arena_walls(16, 16), ()), wheel_sign=-1)
    motors.set_targets(-10.0, -10.0)
    _run(physics, 1.0)
    assert physics.state.x > 0.4
    with pytest.raises(ValueError, match="wheel_sign"):
        DiffDrivePhysics(World(arena_walls(4, 4), ()), motors, GEOMETRY, wheel_sign=2)


def test_placing_the_robot_on_an_obstacle_is_refused() -> None:
    physics, _ = _physics(World(arena_walls(16, 16), (Circle(3.0, 0.0, 0.5),)))
    with pytest.raises(ValueError, match=r"pose \(3.100, 0.000\) puts the robot's footprint"):
        physics.place(Pose(3.1, 0.0, 0.0))
    with pytest.raises(ValueError, match="footprint on an obstacle or wall"):
        physics.place(Pose(7.9, 0.0, 0.0))
    with pytest.raises(ValueError, match="finite"):
        physics.place(Pose(math.nan, 0.0, 0.0))
    physics.place(Pose(-2.0, 1.0, 4.0))
    assert physics.state.theta == pytest.approx(4.0 - 2 * math.pi)


def test_first_contact_against_circles_and_wall_faces() -> None:
    world = World((Segment(2.0, -1.0, 2.0, 1.0),), (Circle(0.0, 3.0, 0.5),))
    assert first_contact(world, 0.0, 0.0, 1.0, 0.0, 0.2) == pytest.approx(1.8)
    assert first_contact(world, 0.0, 0.0, 0.0, 1.0, 0.2) == pytest.approx(2.3)
    assert math.isinf(first_contact(world, 0.0, 0.0, -1.0, 0.0, 0.2))
    # the rounded end of the wall: passing just beside the end point at y = 1.1
    assert first_contact(world, 0.0, 1.1, 1.0, 0.0, 0.2) == pytest.approx(
        2.0 - math.sqrt(0.2**2 - 0.1**2))
    # touching the wall: blocked into it, free along it and away from it
    assert first_contact(world, 1.8, 0.0, 1.0, 0.0, 0.2) == 0.0
    assert math.isinf(first_contact(world, 1.8, 0.0, -1.0, 0.0, 0.2))
    assert first_contact(world, 1.8, 0.0, 0.0, -1.0, 0.2) > 0.9
