# The navigation algorithms (nav/): costmap from scans, the planner around walls and into the
# unknown, its refusals, and the Regulated Pure Pursuit follower on a simulated unicycle.
from __future__ import annotations

import math

import numpy as np
import pytest

from nav.costmap import Costmap, CostParams, GridArea, centred_area, cost_grid
from nav.planner import plan
from nav.pursuit import Pursuit, PursuitSettings, densify, figure_eight, transform

PARAMS = CostParams(radius_m=0.25)


def area(size: float = 10.0, resolution: float = 0.1) -> GridArea:
    return centred_area(resolution, size)


def wall(grid: GridArea, x: float, y0: float, y1: float) -> np.ndarray:
    """Obstacle cells of a wall along y at ``x``."""
    obstacles = np.zeros((grid.height, grid.width), dtype=bool)
    col = grid.cell(x, 0.0)[1]
    rows = range(grid.cell(0.0, y0)[0], grid.cell(0.0, y1)[0] + 1)
    obstacles[list(rows), col] = True
    return obstacles


def length(points: np.ndarray) -> float:
    return float(np.hypot(*np.diff(points, axis=0).T).sum())


def clearance(points: np.ndarray, obstacles: np.ndarray, grid: GridArea) -> float:
    rows, cols = np.nonzero(obstacles)
    ox = grid.origin_x + (cols + 0.5) * grid.resolution
    oy = grid.origin_y + (rows + 0.5) * grid.resolution
    dense = densify(points, 0.02)
    return float(np.hypot(dense[:, :1] - ox, dense[:, 1:] - oy).min())


def test_a_scan_marks_its_returns_and_clears_the_rays() -> None:
    costmap = Costmap(area(), PARAMS)
    angles = np.linspace(-0.3, 0.3, 31)
    costmap.add_scan((0.0, 0.0, 0.0), 2.0 * np.cos(angles), 2.0 * np.sin(angles))
    grid = costmap.area
    assert costmap.obstacles()[grid.cell(2.0, 0.0)]
    assert costmap.seen[grid.cell(1.0, 0.0)] and not costmap.obstacles()[grid.cell(1.0, 0.0)]
    assert not costmap.seen[grid.cell(-2.0, 0.0)]
    costs = costmap.costs()
    assert not math.isfinite(costs[grid.cell(1.9, 0.0)])  # within the footprint's reach
    assert costs[grid.cell(1.0, 0.0)] < costs[grid.cell(-1.0, 0.0)]  # unseen costs more


def test_a_wall_in_the_way_is_planned_around_with_room_for_the_footprint() -> None:
    grid = area()
    obstacles = wall(grid, 0.0, -2.0, 2.0)
    costs = cost_grid(obstacles, np.ones_like(obstacles), grid.resolution, PARAMS)
    found = plan(costs, grid, (-2.0, 0.0), (2.0, 0.0))
    assert found.found, found.reason
    assert tuple(found.points[0]) == (-2.0, 0.0) and tuple(found.points[-1]) == (2.0, 0.0)
    assert clearance(found.points, obstacles, grid) > PARAMS.radius_m
    shortest = 2 * math.hypot(2.0, 2.0 + PARAMS.radius_m)  # round the wall's end
    assert shortest < length(found.points) < 1.2 * shortest


def test_a_straightened_path_keeps_the_line_margin_past_a_corner() -> None:
    grid = area()
    obstacles = wall(grid, 0.0, -5.0, 0.0)
    costs = cost_grid(obstacles, np.ones_like(obstacles), grid.resolution, PARAMS)
    found = plan(costs, grid, (-2.0, -2.0), (2.0, -2.0), line_cost=PARAMS.line_cost)
    banded = plan(costs, grid, (-2.0, -2.0), (2.0, -2.0))  # as far as the band pushes it
    near = clearance(found.points, obstacles, grid)
    # the corner is passed the reach plus the margin away (within a cell), not farther
    assert PARAMS.radius_m + PARAMS.line_margin_m - grid.resolution < near
    assert near < PARAMS.radius_m + PARAMS.line_margin_m + grid.resolution
    assert length(found.points) < length(banded.points)


def round_corner(start: tuple[float, float], corner: tuple[float, float],
                 goal: tuple[float, float], clearance_m: float) -> float:
    """The shortest way from ``start`` to ``goal`` round the far side of a point ``corner``
    at ``clearance_m`` from it: a tangent, an arc, a tangent."""
    legs, bearings = [], []
    for x, y in (start, goal):
        d = math.hypot(x - corner[0], y - corner[1])
        legs.append((math.sqrt(d * d - clearance_m ** 2), math.acos(clearance_m / d)))
        bearings.append(math.atan2(y - corner[1], x - corner[0]))
    between = math.tau - abs(bearings[1] - bearings[0])  # round the side away from both
    return legs[0][0] + legs[1][0] + clearance_m * (between - legs[0][1] - legs[1][1])


def test_a_door_approached_from_beside_its_wall_is_crossed_on_a_diagonal() -> None:
    # a wall along x = 0 with a door 1.2 m wide; start and goal beside the wall, either side:
    # the cheapest grid path crosses the inflation band squarely (a stair of corners before
    # and after the door), the plan takes the shortest way within the same clearance
    grid = area()
    obstacles = wall(grid, 0.0, -5.0, -0.6) | wall(grid, 0.0, 0.6, 4.9)
    costs = cost_grid(obstacles, np.ones_like(obstacles), grid.resolution, PARAMS)
    start, goal = (0.8, 1.0), (-1.0, 1.0)
    found = plan(costs, grid, start, goal, line_cost=PARAMS.line_cost)
    assert found.found, found.reason
    near = clearance(found.points, obstacles, grid)
    assert near > PARAMS.radius_m + grid.resolution  # well clear of the jamb's lethal zone
    rows, cols = np.nonzero(obstacles)
    jamb = min(zip(grid.origin_x + (cols + 0.5) * grid.resolution,
                   grid.origin_y + (rows + 0.5) * grid.resolution, strict=True),
               key=lambda p: math.hypot(p[0] - 0.0, p[1] - 0.6))
    # within 5 % of the shortest way round the jamb at the clearance it keeps (squarely
    # through the door it was 14 % longer)
    assert length(found.points) < 1.05 * round_corner(start, jamb, goal, near)


def test_unseen_space_is_planned_through_at_a_cost() -> None:
    grid = area()
    nothing = np.zeros((grid.height, grid.width), dtype=bool)
    costs = cost_grid(nothing, nothing.copy(), grid.resolution, PARAMS)
    found = plan(costs, grid, (-3.0, -3.0), (3.0, 3.0))
    assert found.found and length(found.points) == pytest.approx(6 * math.sqrt(2), rel=0.01)


def test_an_enclosed_goal_has_no_path_and_a_goal_in_an_obstacle_is_final() -> None:
    grid = area()
    ring = np.zeros((grid.height, grid.width), dtype=bool)
    r0, c0 = grid.cell(2.0, 2.0)
    ring[r0 - 10:r0 + 11, c0 - 10:c0 + 11] = True
    ring[r0 - 9:r0 + 10, c0 - 9:c0 + 10] = False
    costs = cost_grid(ring, np.ones_like(ring), grid.resolution, PARAMS)
    boxed = plan(costs, grid, (-3.0, -3.0), (2.0, 2.0))
    assert not boxed.found and "no path" in boxed.reason and not boxed.final
    inside = plan(costs, grid, (-3.0, -3.0), (2.0, 2.0 + 1.0))
    assert not inside.found and "inside an obstacle" in inside.reason and inside.final
    outside = plan(costs, grid, (-3.0, -3.0), (20.0, 0.0))
    assert not outside.found and "outside the map" in outside.reason and outside.final


def drive(pursuit: Pursuit, pose: tuple[float, float, float], seconds: float,
          dt: float = 0.05) -> tuple[tuple[float, float, float], list[float]]:
    """A unicycle following the commands (first-order speed response)."""
    x, y, theta = pose
    v = 0.0
    errors = []
    for _ in range(round(seconds / dt)):
        command = pursuit.step((x, y, theta), v)
        errors.append(command.cross_track_m)
        if command.phase == "arrived":
            break
        v += 0.5 * (command.v - v)
        theta += command.w * dt
        x += v * dt * math.cos(theta)
        y += v * dt * math.sin(theta)
    return (x, y, theta), errors


def test_the_follower_reaches_the_goal_within_tolerance_and_respects_its_limits() -> None:
    settings = PursuitSettings(max_speed=0.4, max_turn=1.0)
    path = densify(np.array([(0.0, 0.0), (2.0, 0.0), (2.0, 2.0)]), 0.05)
    pursuit = Pursuit(settings, path, math.pi)
    commands = []
    pose = (0.0, 0.0, 0.0)
    for _ in range(2):  # the limits hold on every step
        command = pursuit.step(pose, 0.0)
        commands.append(command)
    assert all(abs(c.v) <= 0.4 and abs(c.w) <= 1.0 for c in commands)
    (x, y, theta), _ = drive(Pursuit(settings, path, math.pi), pose, 40.0)
    assert math.hypot(x - 2.0, y - 2.0) <= settings.xy_tolerance + 0.01
    assert abs(math.remainder(theta - math.pi, math.tau)) <= settings.yaw_tolerance + 0.01


def test_the_follower_turns_at_a_corner_instead_of_cutting_it() -> None:
    path = densify(np.array([(0.0, 0.0), (2.0, 0.0), (2.0, 2.0)]), 0.05)
    corridor = PursuitSettings()
    _, errors = drive(Pursuit(corridor, path, None), (0.0, 0.0, 0.0), 40.0)
    _, cutting = drive(Pursuit(PursuitSettings(corridor=0.0), path, None), (0.0, 0.0, 0.0),
                       40.0)
    assert max(errors) <= corridor.corridor + 0.05
    assert max(cutting) > 2 * max(errors)  # the pure look-ahead cuts the corner


def test_the_follower_turns_in_place_toward_a_path_behind_it() -> None:
    pursuit = Pursuit(PursuitSettings(), densify(np.array([(0.0, 0.0), (-2.0, 0.0)]), 0.05),
                      None)
    command = pursuit.step((0.0, 0.0, 0.0), 0.0)
    assert command.phase == "rotate" and command.v == 0.0 and command.w != 0.0


def test_the_figure_eight_is_tracked_closely() -> None:
    start = (1.0, -2.0, 0.7)
    path = transform(figure_eight(4.0), start)
    assert np.allclose(path[0], start[:2]) and np.allclose(path[-1], start[:2], atol=1e-6)
    pursuit = Pursuit(PursuitSettings(max_speed=0.3), densify(path, 0.05), None)
    _, errors = drive(pursuit, start, 120.0)
    assert pursuit.arrived
    assert math.sqrt(np.mean(np.square(errors))) < 0.05


def test_the_bounded_obstacle_distance_is_exact_within_its_limit() -> None:
    from nav.costmap import obstacle_distance

    rng = np.random.default_rng(1)
    for density in (0.002, 0.05):
        obstacles = rng.random((60, 90)) < density
        exact = obstacle_distance(obstacles)
        bounded = obstacle_distance(obstacles, 6)
        near = exact <= 6
        assert np.allclose(bounded[near], exact[near])
        assert (bounded[~near] > 6).all()


def test_the_guided_search_finds_the_way_through_a_narrow_gap_and_knows_when_there_is_none(
) -> None:
    from nav.planner import cheapest_path, guided_path

    costs = np.ones((100, 100))
    costs[50, :] = np.inf  # a wall across the grid, one gap far to the side
    costs[50, 91] = 1.0
    found, cost = guided_path(costs, (10, 10), (90, 10))
    _, best_cost = cheapest_path(costs, (10, 10), (90, 10))
    assert (50, 91) in found and found[0] == (10, 10) and found[-1] == (90, 10)
    assert best_cost <= cost <= 1.1 * best_cost
    costs[50, 91] = np.inf
    assert guided_path(costs, (10, 10), (90, 10)) == ([], math.inf)


def test_a_lane_one_cell_wide_that_the_blocks_close_is_still_taken() -> None:
    # the lethal zone of a wall across the map leaves one row of free cells through it (a
    # gap the footprint just fits, or a smeared obstacle beside a corridor); the planner's
    # 2 x 2 blocks close it, and the way round the wall's end is three times as long
    grid = area()
    costs = np.ones((grid.height, grid.width))
    band = slice(grid.cell(-0.3, 0.0)[1], grid.cell(0.3, 0.0)[1] + 1)
    costs[: grid.cell(0.0, 4.0)[0], band] = np.inf
    lane = grid.cell(0.0, 0.0)[0]
    costs[lane, band] = 1.0
    found = plan(costs, grid, (-2.0, 0.0), (2.0, 0.0), pool=2)
    assert found.found, found.reason
    assert length(found.points) < 1.1 * 4.0
    rows = [grid.cell(x, y)[0] for x, y in densify(found.points, 0.02) if abs(x) < 0.3]
    assert set(rows) == {lane}
