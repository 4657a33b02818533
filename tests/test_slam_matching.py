# Scan matching and localisation on a synthetic room: offsets recovered, convergence, lost.
from __future__ import annotations

import math

import numpy as np

from slam.field import DistanceField
from slam.grid import OccupancyGrid
from slam.mapper import Mapper, MapperConfig, windows
from slam.matcher import match
from slam.pose import Pose2, between, compose, transform_points, wrap
from tests.slam_room import cast

TRUE_POSE: Pose2 = (3.0, 2.5, 0.4)


def room_grid() -> OccupancyGrid:
    """A map of the room built from scans at known poses."""
    grid = OccupancyGrid(0.05, initial_size=12.0)
    for pose in [(1.0, 1.0, 0.0), (4.0, 1.0, 1.0), (6.5, 3.0, 2.0), (2.5, 4.5, -1.0),
                 (4.0, 3.0, 3.0), (1.0, 5.0, -0.5), (7.0, 1.0, 2.5)]:
        for _ in range(3):
            grid.integrate(pose, cast(pose))
    return grid


def pose_error(a: Pose2, b: Pose2) -> tuple[float, float]:
    d = between(a, b)
    return math.hypot(d[0], d[1]), abs(wrap(d[2]))


def test_matcher_recovers_a_known_offset() -> None:
    reference = cast(TRUE_POSE)
    field = DistanceField.from_points(transform_points(TRUE_POSE, reference), 0.05, 1.0, 0.5)
    guess = compose(TRUE_POSE, (0.12, -0.09, math.radians(4)))
    found = match(field, cast(TRUE_POSE), guess, windows(0.2, math.radians(6), 0.05), 0.05)
    trans, rot = pose_error(found.pose, TRUE_POSE)
    assert trans < 0.02 and rot < math.radians(0.5)  # the field's points are ~1 per cell
    assert found.score > 0.75


def test_localize_converges_from_one_metre_and_thirty_degrees() -> None:
    grid = room_grid()
    mapper = Mapper(MapperConfig(mode="localize"), grid=grid)
    wrong = compose(TRUE_POSE, (0.7, -0.7, math.radians(30)))
    mapper.set_pose(wrong, odom_pose=(0.0, 0.0, 0.0))
    result = mapper.add_scan((0.0, 0.0, 0.0), cast(TRUE_POSE), 0.0)
    for step in range(1, 6):  # then it keeps tracking while the robot moves
        truth = compose(TRUE_POSE, (0.1 * step, 0.0, 0.02 * step))
        result = mapper.add_scan((0.1 * step, 0.0, 0.02 * step), cast(truth), 0.1 * step)
    trans, rot = pose_error(result.pose, truth)
    assert result.matched and not result.lost
    assert trans < 0.05 and rot < math.radians(1)
    assert mapper.grid is grid and grid.version == room_grid().version


def test_localize_reports_lost_on_scans_that_fit_nothing() -> None:
    mapper = Mapper(MapperConfig(mode="localize", lost_after=3), grid=room_grid())
    mapper.set_pose(TRUE_POSE, odom_pose=(0.0, 0.0, 0.0))
    assert mapper.add_scan((0.0, 0.0, 0.0), cast(TRUE_POSE), 0.0).matched
    rng = np.random.default_rng(5)
    results = [mapper.add_scan((0.0, 0.0, 0.0), rng.uniform(-4.0, 4.0, (360, 2)), 0.1 * i)
               for i in range(1, 5)]
    assert not any(r.matched for r in results)
    assert results[-1].lost and mapper.health()["lost"]


def test_mapping_a_drifting_run_tracks_the_truth_better_than_odometry() -> None:
    """Odometry over-reads distance by 5 % and turn by 3 %: the map pose stays close."""
    mapper = Mapper(MapperConfig(loop_closure=False), initial_pose=(1.0, 1.0, 0.0))
    truth: Pose2 = (1.0, 1.0, 0.0)
    odom: Pose2 = (0.0, 0.0, 0.0)
    step = (0.05, 0.0, 0.03)
    for i in range(80):
        truth = compose(truth, step)
        odom = compose(odom, (step[0] * 1.05, 0.0, step[2] * 1.03))
        result = mapper.add_scan(odom, cast(truth), 0.1 * i)
    trans, rot = pose_error(result.pose, truth)
    odom_trans, _ = pose_error(compose((1.0, 1.0, 0.0), odom), truth)
    assert trans < 0.08 and rot < math.radians(2)
    assert odom_trans > 2 * trans
    assert result.pose == compose(result.map_to_odom, odom) or \
        pose_error(result.pose, compose(result.map_to_odom, odom))[0] < 1e-9
    assert len(mapper.trajectory) == 80 and len(result.covariance) == 9
    assert mapper.grid.occupancy().max() == 100
