# The Freiburg relation metric (Kümmerle et al. 2009), as SOURCES.md section 3 defines it.
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slam.pose import Pose2, between, wrap

MATCH_WINDOW_S = 0.1  # a relation end takes the SLAM pose nearest in time within this


@dataclass(frozen=True)
class Relation:
    """The reference pose at ``t2`` in the robot frame at ``t1`` (m, rad)."""

    t1: float
    t2: float
    x: float
    y: float
    yaw: float


@dataclass(frozen=True)
class Stats:
    """mean, sample standard deviation, min, max and count of one error series."""

    mean: float
    std: float
    min: float
    max: float
    n: int


@dataclass(frozen=True)
class RelationErrors:
    """Absolute and squared translational (m, m²) and rotational (rad, rad²) errors."""

    trans: Stats
    rot: Stats
    trans_sq: Stats
    rot_sq: Stats
    unmatched_ends: int  # relation ends with no SLAM pose within MATCH_WINDOW_S (nearest used)


def load_relations(path: Path) -> list[Relation]:
    """``t1 t2 x y z roll pitch yaw`` lines; ``#`` lines are comments."""
    relations = []
    for line in Path(path).read_text(encoding="ascii").splitlines():
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        t1, t2, x, y, _z, _roll, _pitch, yaw = (float(f) for f in fields[:8])
        relations.append(Relation(t1, t2, x, y, yaw))
    return relations


def stats(values: Sequence[float]) -> Stats:
    """Mean and the sample standard deviation sqrt((nΣv² - (Σv)²) / (n(n-1)))."""
    v = np.asarray(values, dtype=np.float64)
    n = len(v)
    if n == 0:
        return Stats(math.nan, math.nan, math.nan, math.nan, 0)
    total, total_sq = float(v.sum()), float((v * v).sum())
    var = (n * total_sq - total * total) / (n * (n - 1)) if n > 1 else 0.0
    return Stats(total / n, math.sqrt(max(var, 0.0)), float(v.min()), float(v.max()), n)


class Trajectory:
    """Time-stamped poses, looked up by nearest stamp."""

    def __init__(self, poses: Sequence[tuple[float, Pose2]]) -> None:
        ordered = sorted(poses, key=lambda item: item[0])
        self.stamps = np.asarray([stamp for stamp, _ in ordered], dtype=np.float64)
        self.poses = [pose for _, pose in ordered]

    def nearest(self, t: float) -> tuple[Pose2, float]:
        """The pose nearest in time to ``t`` and its time distance."""
        i = int(np.searchsorted(self.stamps, t))
        candidates = [j for j in (i - 1, i) if 0 <= j < len(self.stamps)]
        best = min(candidates, key=lambda j: abs(self.stamps[j] - t))
        return self.poses[best], abs(float(self.stamps[best]) - t)


def relation_errors(poses: Sequence[tuple[float, Pose2]],
                    relations: Sequence[Relation]) -> RelationErrors:
    """Per relation: A = p1⁻¹·p2 from the estimate, B from the relation; the translational error
    is |(x, y)(A) - (x, y)(B)| and the rotational one |wrap(yaw(A) - yaw(B))|."""
    if not poses:
        raise ValueError("no poses to evaluate")
    trajectory = Trajectory(poses)
    trans, rot, unmatched = [], [], 0
    for rel in relations:
        p1, gap1 = trajectory.nearest(rel.t1)
        p2, gap2 = trajectory.nearest(rel.t2)
        unmatched += (gap1 > MATCH_WINDOW_S) + (gap2 > MATCH_WINDOW_S)
        ax, ay, ayaw = between(p1, p2)
        trans.append(math.hypot(ax - rel.x, ay - rel.y))
        rot.append(abs(wrap(ayaw - rel.yaw)))
    return RelationErrors(stats(trans), stats(rot), stats([t * t for t in trans]),
                          stats([r * r for r in rot]), unmatched)
