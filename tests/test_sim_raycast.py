# Tests of the vectorised ray caster against hand-computed distances and a scalar reference.
from __future__ import annotations

import math

import numpy as np
import pytest

from sim.raycast import END_CAP_RADIUS, RayCaster, cast, ray_angles
from sim.world import Circle, Segment, World, arena_walls, generated_world

ARENA = World(arena_walls(16.0, 16.0), ())
DEG = math.pi / 180.0


def test_ray_angles_are_one_degree_from_straight_ahead() -> None:
    angles = ray_angles(360)
    assert len(angles) == 360
    assert angles[0] == 0.0
    assert angles[90] == pytest.approx(math.pi / 2)
    assert np.diff(angles) == pytest.approx(np.full(359, DEG))


def test_walls_of_the_arena_from_the_centre() -> None:
    ranges = cast(ARENA, 0.0, 0.0, 0.0, np.array([0, 90, 180, 270]) * DEG)
    assert ranges.tolist() == pytest.approx([8.0, 8.0, 8.0, 8.0], abs=1e-12)


def test_off_centre_robot_sees_each_wall_at_its_distance() -> None:
    ranges = cast(ARENA, 1.0, 2.0, 0.0, np.array([0, 90, 180, 270]) * DEG)
    assert ranges.tolist() == pytest.approx([7.0, 6.0, 9.0, 10.0], abs=1e-12)


def test_heading_rotates_the_fan() -> None:
    # facing +y from (1, 2): ahead is the top wall (6 m), left is the left wall (9 m)
    ranges = cast(ARENA, 1.0, 2.0, math.pi / 2, np.array([0, 90, 180]) * DEG)
    assert ranges.tolist() == pytest.approx([6.0, 9.0, 10.0], abs=1e-12)


def test_diagonal_to_the_corner_and_the_range_limits() -> None:
    diagonal = np.array([45 * DEG])
    assert math.isinf(cast(ARENA, 0.0, 0.0, 0.0, diagonal)[0])  # 11.31 m > 10 m
    assert cast(ARENA, 0.0, 0.0, 0.0, diagonal, range_max=12.0)[0] == pytest.approx(
        8.0 * math.sqrt(2.0))
    near = World((Segment(0.05, -1.0, 0.05, 1.0),), ())
    assert math.isinf(cast(near, 0.0, 0.0, 0.0, np.array([0.0]))[0])  # closer than 0.1 m
    assert cast(near, 0.0, 0.0, 0.0, np.array([0.0]), range_min=0.0)[0] == pytest.approx(0.05)


def test_circle_hits_hand_computed() -> None:
    world = World((), (Circle(4.0, 0.0, 3.0),))
    # towards (0.8, 0.6): t^2 - 6.4 t + 7 = 0, near root (6.4 - 3.6) / 2 = 1.4
    towards = math.atan2(3.0, 4.0)
    ranges = cast(world, 0.0, 0.0, 0.0, np.array([0.0, towards, math.pi, 60 * DEG]))
    assert ranges[0] == pytest.approx(1.0)
    assert ranges[1] == pytest.approx(1.4)
    assert math.isinf(ranges[2])  # pointing away
    assert math.isinf(ranges[3])  # passes beside it (needs sin < 3/4)
    world = World((), (Circle(0.0, 5.0, 1.0),))
    assert cast(world, 0.0, 0.0, 0.0, np.array([90 * DEG]))[0] == pytest.approx(4.0)


def test_segment_hits_hand_computed() -> None:
    wall = World((Segment(2.0, -1.0, 2.0, 1.0),), ())
    inside = math.atan2(0.5, 2.0)
    beside = math.atan2(1.5, 2.0)
    ranges = cast(wall, 0.0, 0.0, 0.0, np.array([0.0, inside, beside, math.pi, 90 * DEG]))
    assert ranges[0] == pytest.approx(2.0)
    assert ranges[1] == pytest.approx(math.hypot(2.0, 0.5))
    assert math.isinf(ranges[2]) and math.isinf(ranges[3]) and math.isinf(ranges[4])
    slanted = World((Segment(1.0, 3.0, 3.0, 1.0),), ())  # the line x + y = 4
    assert cast(slanted, 0.0, 0.0, 0.0, np.array([45 * DEG]))[0] == pytest.approx(
        2.0 * math.sqrt(2.0))


def test_nearest_primitive_wins() -> None:
    world = World(arena_walls(16.0, 16.0), (Circle(3.0, 0.0, 0.5), Circle(5.0, 0.0, 1.0)))
    ranges = cast(world, 0.0, 0.0, 0.0, np.array([0.0, math.pi]))
    assert ranges.tolist() == pytest.approx([2.5, 8.0])
    ranges = cast(world, 7.0, 0.0, 0.0, np.array([0.0, math.pi]))
    assert ranges.tolist() == pytest.approx([1.0, 1.0])  # wall ahead, big circle behind


def _reference(world: World, x: float, y: float, angle: float, rmin: float,
               rmax: float) -> float:
    """Scalar ray cast, written independently of the vectorised one."""
    dx, dy = math.cos(angle), math.sin(angle)
    best = math.inf
    for c in world.circles:
        fx, fy = x - c.x, y - c.y
        b = fx * dx + fy * dy
        disc = b * b - (fx * fx + fy * fy - c.r * c.r)
        if disc >= 0:
            t = -b - math.sqrt(disc)
            if t > 0:
                best = min(best, t)
    for s in world.segments:
        ex, ey = s.x2 - s.x1, s.y2 - s.y1
        den = dx * ey - dy * ex
        if abs(den) < 1e-15:
            continue
        qx, qy = s.x1 - x, s.y1 - y
        t = (qx * ey - qy * ex) / den
        u = (qx * dy - qy * dx) / den
        if t > 0 and 0 <= u <= 1:
            best = min(best, t)
    return best if rmin <= best <= rmax else math.inf


def test_matches_a_scalar_reference_in_generated_worlds() -> None:
    rng = np.random.default_rng(1234)
    angles = ray_angles(360)
    for seed in range(5):
        world = generated_world(seed)
        caster = RayCaster(world, angles)
        for _ in range(8):
            x, y = rng.uniform(-7.5, 7.5, size=2)
            if world.clearance(x, y) < 0.2:
                continue
            theta = rng.uniform(-math.pi, math.pi)
            got = caster.cast(x, y, theta)
            want = [_reference(world, x, y, theta + a, 0.1, 10.0) for a in angles]
            assert np.array_equal(np.isinf(got), np.isinf(want))
            finite = np.isfinite(got)
            assert got[finite] == pytest.approx(np.asarray(want)[finite], abs=1e-9)


def test_empty_world_and_bad_limits() -> None:
    empty_walls = World((), (Circle(2.0, 0.0, 0.5),))
    assert cast(empty_walls, 0.0, 0.0, 0.0, np.array([0.0]))[0] == pytest.approx(1.5)
    no_circles = World((Segment(1.0, -1.0, 1.0, 1.0),), ())
    assert cast(no_circles, 0.0, 0.0, 0.0, np.array([0.0]))[0] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="range_min < range_max"):
        RayCaster(ARENA, ray_angles(), 5.0, 1.0)


def test_a_thin_wall_met_end_on_is_seen() -> None:
    # a zero-thickness wall pointing at the robot: the ray along it would be degenerate, and
    # the rays beside it miss; a real wall has a thickness, and the lidar sees its end
    wall = World((Segment(1.0, 0.0, 3.0, 0.0),), ())
    ahead = cast(wall, 0.0, 0.0, 0.0, ray_angles(360))
    assert ahead[0] == pytest.approx(1.0 - END_CAP_RADIUS, abs=1e-9)
    assert np.isinf(ahead[1:]).all()
    side = cast(wall, 2.0, -1.0, math.pi / 2, np.array([0.0]))  # side-on: the wall itself
    assert side[0] == pytest.approx(1.0)


def test_corners_where_walls_meet_get_no_end_cap() -> None:
    ranges = cast(ARENA, 0.0, 0.0, 0.0, np.array([45.0]) * DEG, range_max=20.0)
    assert ranges[0] == pytest.approx(8.0 * math.sqrt(2.0))


def test_a_caster_with_other_angles_casts_as_a_new_one() -> None:
    """The RPLIDAR emulator's rays move every sample: it reuses the world's geometry."""
    world = generated_world(3, obstacles=6)
    base = RayCaster(world, ray_angles(), 0.1, 10.0)
    angles = np.linspace(-0.3, 2.9, 37)
    moved = base.with_angles(angles)
    fresh = RayCaster(world, angles, 0.1, 10.0)
    for pose in ((0.0, 0.0, 0.0), (1.2, -0.7, 2.0)):
        np.testing.assert_array_equal(moved.cast(*pose), fresh.cast(*pose))
    assert len(base.cast(0.0, 0.0, 0.0)) == 360  # the original keeps its fan
