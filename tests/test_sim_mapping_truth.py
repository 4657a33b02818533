# Ground-truth helpers on hand-made cases: rasterised walls, precision/recall, pose errors,
# the free cells the robot can reach.
from __future__ import annotations

import math

import numpy as np
import pytest

from sim.mapping_truth import (
    GridSpec,
    PoseErrors,
    clearances,
    dilate,
    map_precision_recall,
    reachable_free_cells,
    truth_occupancy,
    visible_walls,
    world_grid,
)
from sim.world import Circle, Pose, Segment, World, arena_walls

RES = 0.05
ONE_WALL = World((Segment(0.01, 0.01, 0.99, 0.01),), (), Pose(0.5, 1.0))


def single_wall_truth() -> np.ndarray:
    return truth_occupancy(ONE_WALL, RES, -0.5, -0.5, 40, 40)


def test_a_single_wall_marks_exactly_the_cells_it_passes_through() -> None:
    truth = single_wall_truth()
    assert truth.shape == (40, 40)  # (height, width), row 0 at origin_y
    assert truth.sum() == 20 and truth[10, 10:30].all()


def test_a_diagonal_wall_marks_every_cell_it_crosses() -> None:
    wall = Segment(0.013, 0.021, 0.961, 0.587)
    truth = truth_occupancy(World((wall,), ()), RES, 0.0, 0.0, 20, 20)
    exact = GridSpec(RES, 0.0, 0.0, 20, 20)
    u = np.linspace(0.0, 1.0, 200_001)  # a far denser reference
    reference = exact.mark(wall.x1 + u * (wall.x2 - wall.x1), wall.y1 + u * (wall.y2 - wall.y1))
    assert np.array_equal(truth, reference)


def test_a_circle_is_its_outline() -> None:
    truth = truth_occupancy(World((), (Circle(0.0, 0.0, 0.3),)), RES, -0.5, -0.5, 20, 20)
    xs, ys = GridSpec(RES, -0.5, -0.5, 20, 20).centres()
    distance = np.hypot(xs, ys)
    assert not truth[distance < 0.3 - RES].any()  # the inside is never seen
    assert truth[np.abs(distance - 0.3) < RES / 4].all()
    assert not truth[distance > 0.3 + RES].any()
    circle = Circle(0.013, -0.021, 0.237)
    truth = truth_occupancy(World((), (circle,)), RES, -0.5, -0.5, 20, 20)
    a = np.linspace(0.0, 2 * math.pi, 400_001)  # a far denser reference
    reference = GridSpec(RES, -0.5, -0.5, 20, 20).mark(circle.x + circle.r * np.cos(a),
                                                       circle.y + circle.r * np.sin(a))
    assert np.array_equal(truth, reference)


def test_a_perfect_map_scores_one_and_one() -> None:
    truth = single_wall_truth()
    assert map_precision_recall(truth, truth) == (1.0, 1.0)
    assert map_precision_recall(truth, truth, tolerance_cells=0) == (1.0, 1.0)


def test_one_cell_off_is_within_tolerance_two_cells_off_is_not() -> None:
    truth = single_wall_truth()
    assert map_precision_recall(np.roll(truth, 1, axis=0), truth) == (1.0, 1.0)
    assert map_precision_recall(np.roll(truth, 2, axis=0), truth) == (0.0, 0.0)
    along = np.roll(truth, 2, axis=1)  # slid along the wall: the overhang is wrong
    precision, recall = map_precision_recall(along, truth)
    assert precision == pytest.approx(19 / 20) and recall == pytest.approx(19 / 20)
    assert map_precision_recall(along, truth, tolerance_cells=2) == (1.0, 1.0)


def test_spurious_cells_cost_precision_missing_cells_cost_recall() -> None:
    truth = single_wall_truth()
    noisy = truth.copy()
    noisy[30, 0:20] = True  # 20 cells of nothing
    assert map_precision_recall(noisy, truth) == (0.5, 1.0)
    half = truth.copy()
    half[:, 20:] = False
    assert map_precision_recall(half, truth) == (1.0, pytest.approx(11 / 20))
    assert map_precision_recall(np.zeros_like(truth), truth) == (0.0, 0.0)


def test_recall_over_observed_walls_ignores_walls_never_seen() -> None:
    truth = single_wall_truth()
    half = truth.copy()
    half[:, 20:] = False
    observed = np.zeros_like(truth)
    observed[10, 10:19] = True  # only the left part was ever hit by a ray
    precision, recall = map_precision_recall(half, truth, observed=observed)
    assert (precision, recall) == (1.0, 1.0)
    assert map_precision_recall(np.zeros_like(truth), truth, observed=observed) == (0.0, 0.0)


def test_shapes_and_tolerance_are_checked() -> None:
    truth = single_wall_truth()
    with pytest.raises(ValueError, match="one shape"):
        map_precision_recall(truth[:10], truth)
    with pytest.raises(ValueError, match="tolerance_cells"):
        map_precision_recall(truth, truth, tolerance_cells=-1)


def test_dilate_is_the_square_around() -> None:
    one = np.zeros((7, 7), dtype=bool)
    one[3, 3] = True
    assert dilate(one, 1).sum() == 9 and dilate(one, 2).sum() == 25
    assert dilate(one, 0).sum() == 1


def test_visible_walls_are_the_walls_the_rays_hit() -> None:
    room = World(arena_walls(4.0, 4.0), (Circle(3.0, 0.0, 0.3),))  # the circle is outside
    grid = world_grid(room, RES, margin=0.1)
    args = (RES, grid.origin_x, grid.origin_y, grid.width, grid.height)
    truth = truth_occupancy(room, *args)
    seen = visible_walls(room, [Pose(0.0, 0.0, 0.0), (0.5, 0.5, 1.0)], *args, rays=720)
    assert seen.any() and not (seen & ~dilate(truth, 1)).any()  # every hit is on a wall
    circle = truth_occupancy(World((), room.circles), *args)
    assert not (seen & dilate(circle, 1)).any()  # hidden behind the wall
    _, recall = map_precision_recall(truth, truth, observed=seen)
    assert recall == 1.0
    walls_only = truth & ~circle
    assert map_precision_recall(walls_only, truth, observed=seen) == (1.0, 1.0)
    assert map_precision_recall(walls_only, truth)[1] < 1.0  # over all: the circle is missed


def test_pose_errors_accumulate_rms_and_max() -> None:
    errors = PoseErrors()
    assert (errors.count, errors.rms_m, errors.max_m, errors.rms_deg, errors.max_deg) == \
        (0, 0.0, 0.0, 0.0, 0.0)
    errors.add(Pose(0.0, 0.0, 0.0), Pose(3.0, 4.0, 0.0))
    errors.add((1.0, 1.0, math.radians(179.0)), (1.0, 1.0, math.radians(-179.0)))  # wraps
    assert errors.count == 2
    assert errors.rms_m == pytest.approx(math.sqrt(25.0 / 2))
    assert errors.max_m == pytest.approx(5.0)
    assert errors.rms_deg == pytest.approx(math.sqrt(4.0 / 2))
    assert errors.max_deg == pytest.approx(2.0)


def test_clearances_match_the_world() -> None:
    world = World(arena_walls(6.0, 4.0), (Circle(1.0, 0.5, 0.4), Circle(-1.5, -1.0, 0.2)))
    rng = np.random.default_rng(3)
    xs, ys = rng.uniform(-2.9, 2.9, 500), rng.uniform(-1.9, 1.9, 500)
    expected = [world.clearance(x, y) for x, y in zip(xs, ys, strict=True)]
    assert np.allclose(clearances(world, xs, ys), expected)


def two_rooms(door: float) -> World:
    """Two 3 x 3 m rooms side by side, a door of ``door`` m in the middle wall, and a closed
    1 x 1 m box in the left room (free inside, never reachable)."""
    walls = [*arena_walls(6.0, 3.0), Segment(0.0, -1.5, 0.0, -door / 2),
             Segment(0.0, door / 2, 0.0, 1.5)]
    box = [Segment(-2.5, 0.2, -1.5, 0.2), Segment(-1.5, 0.2, -1.5, 1.2),
           Segment(-1.5, 1.2, -2.5, 1.2), Segment(-2.5, 1.2, -2.5, 0.2)]
    return World(tuple(walls + box), (), Pose(-1.5, -0.8))


def test_reachable_cells_go_through_a_door_the_footprint_fits() -> None:
    world = two_rooms(door=0.9)
    grid = world_grid(world, RES)
    reached = reachable_free_cells(world, RES, 0.2)
    assert reached[grid.cell_of(1.5, 0.0)]  # the other room
    assert not reached[grid.cell_of(-2.0, 0.7)]  # inside the closed box
    narrow = reachable_free_cells(two_rooms(door=0.35), RES, 0.2)
    assert narrow[grid.cell_of(-1.0, 0.0)] and not narrow[grid.cell_of(1.5, 0.0)]
    assert reached.sum() > 1.9 * narrow.sum()
