# The fusion of per-scan poses with odometry: noise learnt from the data, a robust chain fit.
from __future__ import annotations

import math

import numpy as np

from slam.pose import Pose2, between, compose, wrap
from slam.smooth import SIGMA_FLOOR, learn_noise, smooth


def drive(n: int, seed: int, pose_sigma: float, step_sigma: float,
          odometry_scale: float = 1.0) -> tuple[list[Pose2], list[Pose2], list[Pose2]]:
    """A curving path: the truth, noisy absolute poses and random-walk odometry."""
    rng = np.random.default_rng(seed)
    truth: list[Pose2] = [(0.0, 0.0, 0.0)]
    odometry: list[Pose2] = [(5.0, -2.0, 1.0)]  # odometry's own frame, anywhere
    for i in range(n - 1):
        step = (0.05, 0.0, 0.02 * math.sin(i / 30))
        truth.append(compose(truth[-1], step))
        noisy = (step[0] * odometry_scale + rng.normal(0, step_sigma),
                 rng.normal(0, step_sigma), step[2] * odometry_scale + rng.normal(0, step_sigma))
        odometry.append(compose(odometry[-1], noisy))
    poses = [(x + rng.normal(0, pose_sigma), y + rng.normal(0, pose_sigma),
              wrap(t + rng.normal(0, pose_sigma))) for x, y, t in truth]
    return truth, poses, odometry


def relative_error(poses: list[Pose2], truth: list[Pose2]) -> float:
    errors = []
    for i in range(len(poses) - 1):
        d = between(between(truth[i], truth[i + 1]), between(poses[i], poses[i + 1]))
        errors.append(math.hypot(d[0], d[1]))
    return float(np.mean(errors))


def test_the_noise_is_learnt_from_how_poses_and_odometry_disagree() -> None:
    _, poses, odometry = drive(3000, 1, pose_sigma=0.01, step_sigma=0.004)
    pose_sigma, step_sigma = learn_noise(poses, odometry)
    # pose noise in the pose's frame mixes x/y with θ·lever; within 30 % of the truth
    assert np.all(np.abs(pose_sigma - 0.01) < 0.003), pose_sigma
    assert np.all(np.abs(step_sigma - 0.004) < 0.0015), step_sigma


def test_fusing_with_good_odometry_brings_the_poses_closer_to_the_truth() -> None:
    truth, poses, odometry = drive(600, 2, pose_sigma=0.01, step_sigma=0.002)
    fused = smooth(poses, odometry, *learn_noise(poses, odometry))
    assert relative_error(fused, truth) < 0.5 * relative_error(poses, truth)
    assert len(fused) == len(poses)


def test_biased_odometry_does_not_pull_the_poses_along() -> None:
    """Odometry that over-reads every forward motion by 10 %: its error along x grows with the
    span faster than a random walk's, the learnt x noise of the poses is at the floor, and the
    fused poses keep the poses' lengths, not the odometry's."""
    truth, poses, odometry = drive(600, 3, pose_sigma=0.002, step_sigma=0.0,
                                   odometry_scale=1.1)
    pose_sigma, step_sigma = learn_noise(poses, odometry)
    assert pose_sigma[0] <= 2 * SIGMA_FLOOR
    fused = smooth(poses, odometry, pose_sigma, step_sigma)
    assert relative_error(fused, truth) <= 1.01 * relative_error(poses, truth)


def test_a_wheel_slip_does_not_pull_the_poses() -> None:
    truth, poses, odometry = drive(400, 4, pose_sigma=0.005, step_sigma=0.002)
    slip = 200  # odometry jumps 0.5 m forward between scans 199 and 200, then goes on
    odometry = odometry[:slip] + [compose(o, (0.5, 0.0, 0.0)) for o in odometry[slip:]]
    fused = smooth(poses, odometry, np.full(3, 0.005), np.full(3, 0.002))
    worst = max(math.hypot(a[0] - t[0], a[1] - t[1]) for a, t in zip(fused, truth, strict=True))
    assert worst < 0.03
