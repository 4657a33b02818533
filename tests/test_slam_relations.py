# The Freiburg relation metric on hand-made trajectories: zero on exact poses, known on perturbed.
from __future__ import annotations

import itertools
import math
from pathlib import Path

import pytest

from slam.pose import Pose2, between, compose
from slam.relations import Relation, load_relations, relation_errors, stats

TRUTH: list[tuple[float, Pose2]] = [(float(i), (0.5 * i, 0.1 * i * i, 0.2 * i)) for i in range(10)]


def relations_of(truth: list[tuple[float, Pose2]]) -> list[Relation]:
    out = []
    for (t1, p1), (t2, p2) in itertools.pairwise(truth):
        x, y, yaw = between(p1, p2)
        out.append(Relation(t1, t2, x, y, yaw))
    return out


def test_exact_poses_have_zero_error() -> None:
    errors = relation_errors(TRUTH, relations_of(TRUTH))
    assert errors.trans.mean == pytest.approx(0.0, abs=1e-12)
    assert errors.rot.mean == pytest.approx(0.0, abs=1e-12)
    assert errors.trans.n == 9 and errors.unmatched_ends == 0


def test_a_rigid_offset_of_the_whole_trajectory_costs_nothing() -> None:
    moved = [(t, compose((3.0, -2.0, 1.0), p)) for t, p in TRUTH]
    errors = relation_errors(moved, relations_of(TRUTH))
    assert errors.trans.max < 1e-9 and errors.rot.max < 1e-9


def test_one_perturbed_pose_gives_the_known_error() -> None:
    """Pose 5 moved 0.1 m along its own x and turned 0.05 rad: the relation into it is off by
    exactly that; the relation out of it by the turn (0.05 rad) and the lever arm."""
    perturbed = list(TRUTH)
    perturbed[5] = (5.0, compose(TRUTH[5][1], (0.1, 0.0, 0.05)))
    errors = relation_errors(perturbed, relations_of(TRUTH))
    rel_in = relation_errors(perturbed[4:6], relations_of(TRUTH[4:6]))
    assert rel_in.trans.mean == pytest.approx(0.1, abs=1e-9)
    assert rel_in.rot.mean == pytest.approx(0.05, abs=1e-9)
    assert errors.rot.mean == pytest.approx(0.1 / 9, abs=1e-9)
    out_x, out_y, _ = between(perturbed[5][1], TRUTH[6][1])
    ref = relations_of(TRUTH)[5]
    assert errors.trans.max == pytest.approx(max(0.1, math.hypot(out_x - ref.x, out_y - ref.y)))


def test_poses_are_taken_at_the_nearest_stamp_and_far_ones_are_counted() -> None:
    shifted = [(t + 0.05, p) for t, p in TRUTH]
    assert relation_errors(shifted, relations_of(TRUTH)).unmatched_ends == 0
    late = [(t + 0.2, p) for t, p in TRUTH]
    assert relation_errors(late, relations_of(TRUTH)).unmatched_ends == 18


def test_stats_use_the_sample_standard_deviation() -> None:
    s = stats([1.0, 2.0, 3.0, 4.0])
    assert s.mean == 2.5 and s.std == pytest.approx(math.sqrt(5 / 3)) and s.n == 4


def test_relations_file_format(tmp_path: Path) -> None:
    path = tmp_path / "x.relations"
    path.write_text("# t1 t2 x y z roll pitch yaw\n1.5 2.5 0.1 0.2 0 0 0 0.3\n\n")
    (rel,) = load_relations(path)
    assert (rel.t1, rel.t2, rel.x, rel.y, rel.yaw) == (1.5, 2.5, 0.1, 0.2, 0.3)
