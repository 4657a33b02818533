# SE(2) pose algebra on plain (x, y, theta) tuples, plus vectorised helpers for point sets.
from __future__ import annotations

import math

import numpy as np

Pose2 = tuple[float, float, float]  # x m, y m, theta rad


def wrap(angle: float) -> float:
    """The angle in (-pi, pi]."""
    wrapped = math.remainder(angle, math.tau)
    return math.pi if wrapped == -math.pi else wrapped


def compose(a: Pose2, b: Pose2) -> Pose2:
    """a ∘ b: the pose b given in a's frame, expressed in a's parent frame."""
    ax, ay, at = a
    bx, by, bt = b
    c, s = math.cos(at), math.sin(at)
    return (ax + c * bx - s * by, ay + s * bx + c * by, wrap(at + bt))


def inverse(a: Pose2) -> Pose2:
    """The pose whose composition with ``a`` is the identity."""
    ax, ay, at = a
    c, s = math.cos(at), math.sin(at)
    return (-c * ax - s * ay, s * ax - c * ay, wrap(-at))


def between(a: Pose2, b: Pose2) -> Pose2:
    """inverse(a) ∘ b: the pose b seen from a's frame."""
    return compose(inverse(a), b)


def transform_points(pose: Pose2, points_xy: np.ndarray) -> np.ndarray:
    """Points (N, 2) given in ``pose``'s frame, expressed in its parent frame."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    rotation = np.array([[c, -s], [s, c]], dtype=np.float64)
    return np.asarray(points_xy, dtype=np.float64) @ rotation.T + np.array(pose[:2])
