# The offline far-in-time loop closures: found through a drifted graph, checked in pairs.
from __future__ import annotations

import math

import numpy as np

from slam.farloops import (
    FarLoopConfig,
    candidates,
    consistent,
    corrects,
    far_loops,
    residual,
)
from slam.mapper import Mapper, MapperConfig
from slam.pose import Pose2, between, compose, wrap
from tests.slam_room import cast


def tour() -> tuple[list[Pose2], list[np.ndarray], np.ndarray]:
    """Key scans on a small loop in the room, driven twice 2000 s apart: true poses, points
    and stamps."""
    truths: list[Pose2] = []
    for _lap in range(2):
        for k in range(24):
            angle = 2 * math.pi * k / 24
            truths.append((4.0 + 1.2 * math.cos(angle), 3.0 + 1.0 * math.sin(angle),
                           wrap(angle + math.pi / 2)))
    stamps = np.array([k * 1.0 + (2000.0 if k >= 24 else 0.0) for k in range(len(truths))])
    return truths, [cast(t) for t in truths], stamps


def drifted(truths: list[Pose2], offset: Pose2) -> np.ndarray:
    """The second lap moved as a whole by ``offset`` (a map bent far away by bad matches)."""
    return np.asarray([t if k < 24 else compose(offset, t) for k, t in enumerate(truths)])


def test_the_second_lap_is_found_through_a_drifted_graph_and_placed_right() -> None:
    truths, points, stamps = tour()
    poses = drifted(truths, (12.0, -9.0, math.radians(20)))  # far beyond the online reach
    odometry = drifted(truths, (3.0, -2.0, math.radians(4)))  # odometry drifts less
    kept, counts = far_loops(poses, points, odometry, stamps,
                             FarLoopConfig(query_every=2, candidate_keys=6), 0.05)
    assert counts["far_candidates"] >= 8 and len(kept) >= 8
    for i, j, relative, score in kept:
        assert j >= 24 > i and score >= 0.35
        error = between(relative, between(truths[i], truths[j]))
        assert math.hypot(error[0], error[1]) < 0.05 and abs(error[2]) < math.radians(0.5)


def test_nothing_is_paired_when_the_visits_are_close_in_time_or_already_in_reach() -> None:
    truths, _, stamps = tour()
    poses = np.asarray(truths)
    cfg = FarLoopConfig(query_every=1)
    assert candidates(poses, poses, stamps, cfg) == []  # the graph already has them together
    assert candidates(drifted(truths, (12.0, 0.0, 0.0)), poses, stamps * 0.1, cfg) == []


def test_a_closure_no_neighbour_agrees_with_is_dropped() -> None:
    truths, _, _ = tour()
    poses = np.asarray(truths)
    right = [(i, i + 24, between(truths[i], truths[i + 24]), 0.8) for i in range(0, 8, 2)]
    wrong = (3, 27, compose(between(truths[3], truths[27]), (1.5, 0.0, 0.0)), 0.9)
    kept = consistent(poses, [*right, wrong], FarLoopConfig())
    assert wrong not in kept and len(kept) == len(right)
    assert all(max(residual(poses, c)) < 1e-9 for c in right)


def test_a_mapper_whose_log_has_no_late_return_is_left_as_it_was() -> None:
    mapper = Mapper(MapperConfig(), initial_pose=(1.0, 1.0, 0.0))
    truth: Pose2 = (1.0, 1.0, 0.0)
    for i in range(40):
        truth = compose(truth, (0.08, 0.0, 0.02))
        mapper.add_scan(compose((-1.0, -1.0, 0.0), truth), cast(truth), 0.1 * i)
    mapper.optimize()
    before = mapper.trajectory
    counts = mapper.close_far_loops()
    assert counts == {"far_candidates": 0, "far_strong": 0, "far_agreeing": 0,
                      "far_accepted": 0}
    assert mapper.trajectory == before


def test_only_closures_that_move_the_graph_beyond_the_online_reach_are_kept() -> None:
    truths, _, _ = tour()
    poses = np.asarray(truths)
    agreeing = (2, 26, between(truths[2], truths[26]), 0.8)
    moving = (2, 26, compose(between(truths[2], truths[26]), (1.5, 0.0, 0.0)), 0.8)
    turning = (2, 26, compose(between(truths[2], truths[26]), (0.0, 0.0, math.radians(8))), 0.8)
    cfg = FarLoopConfig()
    assert not corrects(poses, agreeing, cfg)
    assert corrects(poses, moving, cfg) and corrects(poses, turning, cfg)
