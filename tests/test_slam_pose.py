# Pose algebra properties: identity, inverse, associativity, between, wrap.
from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from slam.pose import Pose2, between, compose, inverse, transform_points, wrap

coord = st.floats(-50, 50, allow_nan=False)
angle = st.floats(-10, 10, allow_nan=False)
poses = st.tuples(coord, coord, angle)


def close(a: Pose2, b: Pose2, tol: float = 1e-7) -> bool:
    return (abs(a[0] - b[0]) < tol and abs(a[1] - b[1]) < tol
            and abs(wrap(a[2] - b[2])) < tol)


@given(angle)
def test_wrap_lands_in_half_open_interval(a: float) -> None:
    w = wrap(a)
    assert -math.pi < w <= math.pi
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)


def test_wrap_of_minus_pi_is_pi() -> None:
    assert wrap(-math.pi) == math.pi


@given(poses)
def test_inverse_composes_to_identity(a: Pose2) -> None:
    assert close(compose(a, inverse(a)), (0.0, 0.0, 0.0))
    assert close(compose(inverse(a), a), (0.0, 0.0, 0.0))


@given(poses, poses, poses)
def test_compose_is_associative(a: Pose2, b: Pose2, c: Pose2) -> None:
    assert close(compose(compose(a, b), c), compose(a, compose(b, c)), 1e-6)


@given(poses, poses)
def test_between_recovers_the_second_pose(a: Pose2, b: Pose2) -> None:
    assert close(compose(a, between(a, b)), b, 1e-6)


@given(poses, st.tuples(coord, coord))
def test_transform_points_agrees_with_compose(a: Pose2, p: tuple[float, float]) -> None:
    moved = transform_points(a, np.array([p]))[0]
    expected = compose(a, (p[0], p[1], 0.0))
    assert np.allclose(moved, expected[:2], atol=1e-7)
