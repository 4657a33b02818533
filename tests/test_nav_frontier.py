# Frontier exploration's pure part (nav/frontier.py): frontier cells, the gaps between rays
# filled, clusters the robot can reach ranked by the way there and their size, the blacklist.
from __future__ import annotations

import numpy as np

from nav.costmap import CostParams, GridArea, centred_area, cost_grid
from nav.frontier import choose, find_frontiers, frontier_cells, known_free_m2, without_small_holes

PARAMS = CostParams(radius_m=0.25)


def room(grid: GridArea, gap: bool) -> tuple[np.ndarray, np.ndarray]:
    """Known cells left of x = 1 m; a wall along x = 0.5 m with a 1.2 m doorway at y = 0
    (``gap``) or none: (seen, obstacles)."""
    xs = grid.origin_x + (np.arange(grid.width) + 0.5) * grid.resolution
    ys = grid.origin_y + (np.arange(grid.height) + 0.5) * grid.resolution
    x, y = np.meshgrid(xs, ys)
    seen = x < 1.0
    obstacles = (np.abs(x - 0.55) < 0.05) & ~(gap & (np.abs(y) < 0.6))
    return seen, obstacles


def test_frontier_cells_are_known_free_cells_beside_the_unknown() -> None:
    unknown = np.zeros((5, 5), dtype=bool)
    unknown[:, 3:] = True
    free = ~unknown
    free[0, 2] = False  # an obstacle on the boundary is no frontier
    cells = frontier_cells(free, unknown)
    assert np.array_equal(np.nonzero(cells)[0], [1, 2, 3, 4])
    assert set(np.nonzero(cells)[1]) == {2}


def test_small_enclosed_pockets_of_unknown_count_as_known() -> None:
    unknown = np.zeros((20, 20), dtype=bool)
    unknown[5, 5] = unknown[10, 10:12] = True  # gaps between rays
    unknown[:, 15:] = True  # the unexplored side, touching the edge
    unknown[0:2, 0:2] = True  # small but at the edge: still unknown
    left = without_small_holes(unknown, max_cells=10)
    assert not left[5, 5] and not left[10, 10:12].any()
    assert left[:, 15:].all() and left[0:2, 0:2].all()


def test_a_frontier_behind_a_doorway_is_found_with_the_way_there() -> None:
    grid = centred_area(0.1, 10.0)
    seen, obstacles = room(grid, gap=True)
    costs = cost_grid(obstacles, seen, grid.resolution, PARAMS)
    found = find_frontiers(costs, seen, obstacles, grid, (-3.0, 0.0))
    assert len(found) == 1
    frontier = found[0]
    assert abs(frontier.x - 0.95) < 0.06 and abs(frontier.y) < 0.5
    assert frontier.size_m > 9.0  # the whole column along x = 1 m
    assert 3.9 < frontier.cost_m < 6.0  # about 4 m of free way, dearer through the doorway


def test_a_frontier_walled_off_from_the_robot_is_not_reachable() -> None:
    grid = centred_area(0.1, 10.0)
    seen, obstacles = room(grid, gap=False)
    costs = cost_grid(obstacles, seen, grid.resolution, PARAMS)
    assert find_frontiers(costs, seen, obstacles, grid, (-3.0, 0.0)) == []
    # the same frontier from the other side of the wall is reachable
    assert len(find_frontiers(costs, seen, obstacles, grid, (0.8, 3.0))) == 1


def test_nothing_known_nothing_found_and_the_known_free_area() -> None:
    grid = centred_area(0.1, 4.0)
    seen = np.zeros((grid.height, grid.width), dtype=bool)
    costs = cost_grid(seen, seen, grid.resolution, PARAMS)
    assert find_frontiers(costs, seen, seen, grid, (0.0, 0.0)) == []
    seen[:10, :] = True
    obstacles = np.zeros_like(seen)
    obstacles[0, :] = True
    assert abs(known_free_m2(seen, obstacles, 0.1) - 9 * 40 * 0.01) < 1e-9


def test_the_cheapest_frontier_is_chosen_unless_blacklisted() -> None:
    grid = centred_area(0.1, 10.0)
    xs = grid.origin_x + (np.arange(grid.width) + 0.5) * grid.resolution
    x, _ = np.meshgrid(xs, xs)
    seen = np.abs(x) < 2.0  # a known band with the unknown on both sides
    obstacles = np.zeros_like(seen)
    costs = cost_grid(obstacles, seen, grid.resolution, PARAMS)
    found = find_frontiers(costs, seen, obstacles, grid, (1.0, 0.0))
    assert len(found) == 2
    best = choose(found, size_weight=0.1)
    assert best is not None and best.x > 1.5  # the near side
    other = choose(found, 0.1, blacklist=[(best.x, best.y)])
    assert other is not None and other.x < -1.5
    assert choose(found, 0.1, blacklist=[(best.x, best.y), (other.x, other.y)]) is None
