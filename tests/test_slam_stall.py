# The mapper across a stalled odometry stream that then reports the stalled motion in a jump.
from __future__ import annotations

import math

from slam.mapper import Mapper, MapperConfig
from slam.pose import Pose2, between
from tests.slam_room import cast

STEP = math.radians(5)  # the robot turns in place by this much a scan


def _run(config: MapperConfig, stalls: range) -> tuple[Mapper, list[Pose2], list[Pose2]]:
    """The robot turns in place at (3, 3) by ``STEP`` a scan for 20 scans; the odometry
    (exact otherwise) repeats its last pose on the scans ``stalls`` and then reports all the
    turn at once. Returns the mapper, the true poses and the mapper's poses."""
    mapper = Mapper(config)
    truth, estimates = [], []
    odom: Pose2 = (0.0, 0.0, 0.0)
    for i in range(20):
        pose = (3.0, 3.0, i * STEP)
        if i not in stalls:
            odom = (0.0, 0.0, i * STEP)
        result = mapper.add_scan(odom, cast(pose), float(i))
        truth.append(pose)
        estimates.append(result.pose)
    return mapper, truth, estimates


def _worst_heading_error(truth: list[Pose2], estimates: list[Pose2]) -> float:
    """The largest error of a scan-to-scan turn (rad), against the first pose."""
    start_true, start_est = truth[0], estimates[0]
    return max(abs(between(start_true, t)[2] - between(start_est, e)[2])
               for t, e in zip(truth, estimates, strict=True))


def test_the_jump_after_a_stalled_odometry_is_not_counted_twice() -> None:
    """Eight scans with a stalled odometry: the matcher follows the turn there (5° a scan is
    inside its ± 6° window), then the odometry jumps by the whole 45°. Matched around the pose
    before the stall plus the odometry since, the scan after the jump lands within 1°;
    matched only around the usual prediction (the jump on top of the 40° already followed)
    it does not."""
    config = MapperConfig(loop_closure=False)
    mapper, truth, estimates = _run(config, range(4, 12))
    assert _worst_heading_error(truth, estimates) < math.radians(1)
    assert mapper._counts.extra["stall_taken"] >= 1
    _, truth, unaided = _run(MapperConfig(loop_closure=False, stall_follow=0), range(4, 12))
    assert _worst_heading_error(truth, unaided) > math.radians(5)


def test_a_stall_while_standing_still_changes_nothing() -> None:
    """The robot stands still while the odometry repeats itself: both predictions agree, so
    no second match is made."""
    mapper = Mapper(MapperConfig(loop_closure=False))
    for i in range(10):
        mapper.add_scan((0.0, 0.0, 0.0), cast((3.0, 3.0, 0.0)), float(i))
    assert mapper._counts.extra.get("stall_resumed", 0) == 0
