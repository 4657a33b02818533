# Tests of the simulator's noise: seeded, of the configured size, and exactly off when off.
from __future__ import annotations

import math

import numpy as np
import pytest

from sim.noise import GaussianStream, Noise, NoiseConfig
from sim.physics import DiffDrivePhysics, RobotGeometry, make_motors
from sim.world import World, arena_walls

ARENA = World(arena_walls(40.0, 40.0), ())


def test_noise_off_returns_ranges_and_encoders_exactly() -> None:
    noise = Noise(NoiseConfig(enabled=False))
    ranges = np.array([1.0, 2.5, np.inf])
    assert noise.lidar(ranges) is ranges
    assert noise.encoder_offsets() == (0.0, 0.0)
    assert NoiseConfig(enabled=False, wheel_slip=0.3).slip == 0.0


def test_lidar_noise_has_the_configured_sigma_and_keeps_no_returns() -> None:
    noise = Noise(NoiseConfig(lidar_sigma=0.02, seed=3))
    truth = np.full(360, 4.0)
    truth[::10] = np.inf
    samples = np.concatenate([noise.lidar(truth) for _ in range(100)])
    assert np.isinf(samples).sum() == 36 * 100
    errors = samples[np.isfinite(samples)] - 4.0
    assert abs(errors.mean()) < 0.001
    assert errors.std() == pytest.approx(0.02, rel=0.05)


def test_streams_are_seeded_and_independent_of_block_boundaries() -> None:
    seq = np.random.SeedSequence(9)
    one = GaussianStream(seq, block=7)
    two = GaussianStream(np.random.SeedSequence(9), block=4096)
    pieces = np.concatenate([one.take(3), one.take(10), one.take(1), one.take(20)])
    assert np.array_equal(pieces, two.take(34))
    other = GaussianStream(np.random.SeedSequence(10))
    assert not np.array_equal(other.take(34), pieces)


def test_same_seed_same_noise_other_seed_other_noise() -> None:
    ranges = np.full(50, 3.0)
    first, again = Noise(NoiseConfig(seed=4)), Noise(NoiseConfig(seed=4))
    assert np.array_equal(first.lidar(ranges), again.lidar(ranges))
    assert first.encoder_offsets() == again.encoder_offsets()
    assert not np.array_equal(Noise(NoiseConfig(seed=5)).lidar(ranges), again.lidar(ranges))


def test_lidar_and_encoder_streams_do_not_disturb_each_other() -> None:
    quiet, busy = Noise(NoiseConfig(seed=2)), Noise(NoiseConfig(seed=2))
    busy.lidar(np.ones(1000))  # extra scans must not change the encoder noise
    assert quiet.encoder_offsets() == busy.encoder_offsets()


def test_encoder_noise_is_bounded_reading_error_not_drift() -> None:
    geometry = RobotGeometry()
    motors = make_motors()
    physics = DiffDrivePhysics(ARENA, motors, geometry, Noise(NoiseConfig(seed=8)))
    motors.set_targets(4.0, 4.0)
    errors = []
    for _ in range(1500):  # 30 s of driving
        physics.step(0.02)
        encoder_m = motors.positions()[0] * geometry.wheel_radius
        errors.append(encoder_m - physics.state.x)
    spread = np.asarray(errors)
    assert spread.std() == pytest.approx(0.005, rel=0.1)
    assert abs(spread[-1]) < 6 * 0.005  # no random walk after 1500 steps
    assert physics.state.y == pytest.approx(0.0, abs=1e-12)  # the true motion is clean


def test_a_still_wheel_keeps_its_reading() -> None:
    motors = make_motors()
    physics = DiffDrivePhysics(ARENA, motors, RobotGeometry(), Noise(NoiseConfig(seed=1)))
    before = motors.positions()
    for _ in range(100):
        physics.step(0.02)
    assert motors.positions() == before
    assert (physics.state.x, physics.state.y) == (0.0, 0.0)


def test_bad_noise_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="sigmas"):
        NoiseConfig(lidar_sigma=-1.0)
    with pytest.raises(ValueError, match="wheel_slip"):
        NoiseConfig(wheel_slip=1.0)
    assert math.isfinite(NoiseConfig().odom_sigma)
