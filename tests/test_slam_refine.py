# The offline refinement: polish converges where Gauss-Newton swings; the refined trajectory.
from __future__ import annotations

import math

import numpy as np

from slam.field import DistanceField
from slam.mapper import Mapper, MapperConfig
from slam.matcher import _huber_cost, polish, refine
from slam.pose import Pose2, between, compose, transform_points, wrap
from tests.slam_room import cast

TRUE_POSE: Pose2 = (3.0, 2.5, 0.4)


def pose_error(a: Pose2, b: Pose2) -> tuple[float, float]:
    d = between(a, b)
    return math.hypot(d[0], d[1]), abs(wrap(d[2]))


def loss(field: DistanceField, points: np.ndarray, pose: Pose2) -> float:
    d, _ = field.lookup_cells(field.to_cells(transform_points(pose, points)), gradient=False)
    return _huber_cost(d, 0.1, field.max_distance * 0.99)


def test_polish_recovers_a_small_offset_and_never_raises_the_loss() -> None:
    field = DistanceField.from_points(transform_points(TRUE_POSE, cast(TRUE_POSE)), 0.05,
                                      1.0, 0.5)
    scan = cast(TRUE_POSE, beams=720)  # other rays than the field's: not a copy of it
    for offset in [(0.04, -0.03, math.radians(1.5)), (-0.02, 0.05, math.radians(-2))]:
        start = compose(TRUE_POSE, offset)
        polished = polish(field, scan, start)
        trans, rot = pose_error(polished, TRUE_POSE)
        # the loss's minimum on one scan's field is not exactly the truth (within 3 cm here)
        assert trans < 0.03 and rot < math.radians(0.5)
        assert loss(field, scan, polished) <= loss(field, scan, start)
        # converged: at least as low as plain Gauss-Newton's end
        gauss_newton = refine(field, scan, start, 0.05).pose
        assert loss(field, scan, polished) <= loss(field, scan, gauss_newton) + 1e-9


def test_the_refined_trajectory_has_every_scan_and_is_closer_to_the_truth() -> None:
    """A drifting run through the room (odometry over-reads distance by 5 %, turn by 3 %)."""
    mapper = Mapper(MapperConfig(loop_closure=False), initial_pose=(1.0, 1.0, 0.0))
    truth: Pose2 = (1.0, 1.0, 0.0)
    odom: Pose2 = (0.0, 0.0, 0.0)
    truths, scans = [], []
    rng = np.random.default_rng(3)
    for i in range(80):
        truth = compose(truth, (0.05, 0.0, 0.03))
        odom = compose(odom, (0.05 * 1.05, 0.0, 0.03 * 1.03))
        points = cast(truth) + rng.normal(0.0, 0.01, (360, 2))  # 1 cm of range noise
        mapper.add_scan(odom, points, 0.1 * i)
        truths.append(truth)
        scans.append(points)
    online = mapper.trajectory
    refined = mapper.refined_trajectory(scans)
    assert [stamp for stamp, _ in refined] == [stamp for stamp, _ in online]

    def mean_relative_error(poses: list[tuple[float, Pose2]]) -> float:
        errors = [pose_error(between(poses[i][1], poses[i + 1][1]),
                             between(truths[i], truths[i + 1]))[0] for i in range(len(poses) - 1)]
        return float(np.mean(errors))

    assert mean_relative_error(refined) < mean_relative_error(online)
    assert mapper.trajectory == online  # the graph and the map are left as they are


def test_the_refinement_fuses_the_odometry_when_it_is_given() -> None:
    """Odometry with a little random-walk noise (no bias) beside scans with 2 cm of range
    noise: the fused trajectory's steps are closer to the truth's than the polished ones'."""
    mapper = Mapper(MapperConfig(loop_closure=False), initial_pose=(1.0, 1.0, 0.0))
    truth: Pose2 = (1.0, 1.0, 0.0)
    odom: Pose2 = (0.0, 0.0, 0.0)
    truths, scans, odometry = [], [], []
    rng = np.random.default_rng(5)
    for i in range(120):
        step = (0.03, 0.0, 0.02)
        truth = compose(truth, step)
        odom = compose(odom, (step[0] + rng.normal(0, 0.001), rng.normal(0, 0.001),
                              step[2] + rng.normal(0, 0.0005)))
        points = cast(truth) + rng.normal(0.0, 0.02, (360, 2))
        mapper.add_scan(odom, points, 0.1 * i)
        truths.append(truth)
        scans.append(points)
        odometry.append(odom)
    polished = mapper.refined_trajectory(scans)
    fused = mapper.refined_trajectory(scans, odometry=odometry)
    assert [stamp for stamp, _ in fused] == [stamp for stamp, _ in polished]

    def mean_step_error(poses: list[tuple[float, Pose2]]) -> float:
        return float(np.mean([pose_error(between(poses[i][1], poses[i + 1][1]),
                                         between(truths[i], truths[i + 1]))[0]
                              for i in range(len(poses) - 1)]))

    assert mean_step_error(fused) < mean_step_error(polished)
