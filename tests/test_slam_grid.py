# Occupancy grid: ray integration semantics, growth and its bound, the nav_msgs round trip.
from __future__ import annotations

import math

import numpy as np
import pytest

from slam.grid import OccupancyGrid


def cell(grid: OccupancyGrid, x: float, y: float) -> int:
    col, row = grid.cell_of(np.array([[x, y]]))[0]
    return int(grid.occupancy()[row, col])


def test_a_ray_frees_its_path_and_marks_its_end() -> None:
    grid = OccupancyGrid(0.1, initial_size=10.0)
    version = grid.version
    grid.integrate((0.0, 0.0, 0.0), np.array([[2.0, 0.0]]))
    assert grid.version > version
    assert cell(grid, 2.0, 0.0) > 50  # occupied at the end
    for x in (0.05, 0.5, 1.0, 1.85):
        assert cell(grid, x, 0.0) < 50  # free along the ray
    assert cell(grid, 3.0, 0.0) == -1 and cell(grid, 1.0, 1.0) == -1  # unseen: unknown


def test_rays_use_the_pose() -> None:
    grid = OccupancyGrid(0.1, initial_size=10.0)
    grid.integrate((1.0, 1.0, math.pi / 2), np.array([[2.0, 0.0]]))
    assert cell(grid, 1.0, 3.0) > 50 and cell(grid, 1.0, 2.0) < 50


def test_repeated_hits_saturate_at_100_and_repeated_misses_at_0() -> None:
    grid = OccupancyGrid(0.1, initial_size=10.0)
    for _ in range(30):
        grid.integrate((0.0, 0.0, 0.0), np.array([[2.0, 0.0]]))
    assert cell(grid, 2.0, 0.0) == 100 and cell(grid, 1.0, 0.0) == 0
    assert grid.log_odds.dtype == np.float32 and grid.occupancy().dtype == np.int8


def test_one_scan_updates_a_cell_once_however_many_rays_cross_it() -> None:
    grid = OccupancyGrid(0.1, initial_size=10.0)
    fan = np.array([[3.0, y] for y in np.linspace(-0.05, 0.05, 20)])
    grid.integrate((0.0, 0.0, 0.0), fan)
    col, row = grid.cell_of(np.array([[0.55, 0.0]]))[0]
    assert grid.log_odds[row, col] == pytest.approx(grid.miss_log_odds)


def test_the_grid_grows_to_cover_far_points_and_keeps_what_it_had() -> None:
    grid = OccupancyGrid(0.1, initial_size=4.0)
    grid.integrate((0.0, 0.0, 0.0), np.array([[1.0, 0.0]]))
    before = cell(grid, 1.0, 0.0)
    grid.integrate((0.0, 0.0, 0.0), np.array([[-15.0, 12.0]]))
    assert grid.width * 0.1 > 15 and grid.height * 0.1 > 12
    assert cell(grid, 1.0, 0.0) == before and cell(grid, -15.0, 12.0) > 50
    assert grid.dropped_points == 0


def test_the_grid_never_exceeds_its_cell_budget_and_counts_dropped_points() -> None:
    grid = OccupancyGrid(0.1, max_cells=100 * 100, initial_size=4.0)
    grid.integrate((0.0, 0.0, 0.0), np.array([[50.0, 0.0], [2.0, 0.0]]))
    assert grid.width * grid.height <= 100 * 100
    assert grid.dropped_points == 1
    assert cell(grid, 2.0, 0.0) > 50


def test_from_occupancy_round_trips_exactly() -> None:
    rng = np.random.default_rng(3)
    occ = rng.integers(-1, 101, size=(40, 60)).astype(np.int8)
    occ[0, :5] = [-1, 0, 50, 100, 1]
    grid = OccupancyGrid.from_occupancy(occ, 0.05, -1.5, 2.0)
    assert (grid.width, grid.height, grid.resolution) == (60, 40, 0.05)
    assert (grid.origin_x, grid.origin_y) == (-1.5, 2.0)
    np.testing.assert_array_equal(grid.occupancy(), occ)


def test_from_occupancy_refuses_bad_values() -> None:
    with pytest.raises(ValueError, match=r"-1 or 0\.\.100"):
        OccupancyGrid.from_occupancy(np.full((3, 3), 101), 0.05, 0.0, 0.0)


def test_copy_is_independent() -> None:
    grid = OccupancyGrid(0.1, initial_size=4.0)
    twin = grid.copy()
    grid.integrate((0.0, 0.0, 0.0), np.array([[1.0, 0.0]]))
    assert not twin.log_odds.any() and grid.log_odds.any()


def test_memory_figure_for_40_by_40_metres() -> None:
    occ = np.full((800, 800), -1, dtype=np.int8)
    grid = OccupancyGrid.from_occupancy(occ, 0.05, 0.0, 0.0)
    assert grid.nbytes == 640_000 * 4
