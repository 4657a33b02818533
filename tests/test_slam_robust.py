# Mapper robustness: bounded loop-closure matches, wrong closures dropped, localisation converging.
from __future__ import annotations

import math

from slam.field import DistanceField
from slam.graph import PoseGraph
from slam.mapper import Mapper, MapperConfig, windows
from slam.matcher import match
from slam.pose import Pose2, between, compose, transform_points
from tests.slam_room import cast

TRUE_POSE: Pose2 = (3.0, 2.5, 0.4)


def test_a_bounded_match_never_leaves_its_window() -> None:
    """The truth lies 0.45 m outside a ± 0.1 m window: Gauss-Newton alone would slide towards
    it (it is unbounded); bounded, the answer stays inside the window searched."""
    field = DistanceField.from_points(transform_points(TRUE_POSE, cast(TRUE_POSE)), 0.05, 1.0,
                                      0.5)
    prior = compose(TRUE_POSE, (0.45, 0.0, 0.0))
    search = windows(0.1, math.radians(3), 0.05)
    free = match(field, cast(TRUE_POSE), prior, search, 0.05)
    bounded = match(field, cast(TRUE_POSE), prior, search, 0.05, bounded=True)
    moved = between(prior, bounded.pose)
    assert math.hypot(moved[0], moved[1]) <= 0.1 * math.sqrt(2) + 1e-9
    assert abs(moved[2]) <= math.radians(3) + 1e-9
    free_moved = between(prior, free.pose)
    assert math.hypot(free_moved[0], free_moved[1]) > math.hypot(moved[0], moved[1])


def _square_graph(wrong: bool) -> PoseGraph:
    """A 4 x 4 m square of 16 nodes (1 m steps, turning 90° at the corners) with a true loop
    closure from the last node back to the first, and optionally a wrong one (2 m off)."""
    graph = PoseGraph()
    pose: Pose2 = (0.0, 0.0, 0.0)
    graph.add_node(pose)
    for i in range(1, 16):
        step = (1.0, 0.0, math.pi / 2 if i % 4 == 0 else 0.0)
        nxt = compose(pose, step)
        graph.add_node(compose(nxt, (0.0, 0.0, 0.02)))  # a little drift in the estimate
        graph.add_edge(i - 1, i, step, (0.03, 0.03, math.radians(0.5)))
        pose = nxt
    graph.add_edge(15, 0, between(pose, (0.0, 0.0, 0.0)), (0.05, 0.05, math.radians(1)),
                   robust=True)
    if wrong:
        graph.add_edge(8, 0, (2.0, 0.0, 0.0), (0.05, 0.05, math.radians(1)), robust=True)
    return graph


def test_a_wrong_loop_closure_is_dropped_and_the_true_one_kept() -> None:
    graph = _square_graph(wrong=True)
    graph.optimize()
    assert graph.drop_robust_outliers(0.3, math.radians(5)) == 1
    graph.optimize()
    clean = _square_graph(wrong=False)
    clean.optimize()
    assert graph.edge_count == clean.edge_count
    for i in range(16):
        assert math.dist(graph.pose(i)[:2], clean.pose(i)[:2]) < 1e-3


def test_localisation_in_the_apartment_converges_from_one_metre_and_thirty_degrees() -> None:
    """The apartment's true walls as the saved map; the robot drives 5 s (50 revolutions of
    360 rays) starting 1 m / 30° away from where it is told it is: within 0.05 m by then."""
    import numpy as np

    from sim.mapping_truth import truth_occupancy, world_grid
    from sim.raycast import RayCaster
    from sim.world import load_world
    from slam.grid import OccupancyGrid
    from slam.mapper import Mapper, MapperConfig

    world = load_world("apartment")
    spec = world_grid(world, 0.05, margin=1.0)
    walls = truth_occupancy(world, 0.05, spec.origin_x, spec.origin_y, spec.width, spec.height)
    grid = OccupancyGrid.from_occupancy(np.where(walls, 100, 0), 0.05, spec.origin_x,
                                        spec.origin_y)
    angles = np.arange(360) * (2 * math.pi / 360)
    caster = RayCaster(world, angles)
    truth: Pose2 = (world.start.x, world.start.y, world.start.theta)
    for bearing, heading in ((0.0, 30.0), (2.2, -30.0), (4.4, 30.0)):
        told = compose(truth, (math.cos(bearing), math.sin(bearing), math.radians(heading)))
        mapper = Mapper(MapperConfig(mode="localize"), grid=grid)
        mapper.set_pose(told, odom_pose=(0.0, 0.0, 0.0))
        pose, odom = truth, (0.0, 0.0, 0.0)
        for i in range(50):  # 0.2 m/s and 0.2 rad/s at 10 Hz
            pose, odom = compose(pose, (0.02, 0.0, 0.02)), compose(odom, (0.0204, 0.0, 0.0196))
            ranges = caster.cast(*pose)
            ok = np.isfinite(ranges) & (ranges < 12.0)
            points = np.column_stack([ranges[ok] * np.cos(angles[ok]),
                                      ranges[ok] * np.sin(angles[ok])])
            result = mapper.add_scan(odom, points, 0.1 * i)
        assert math.dist(result.pose[:2], pose[:2]) <= 0.05
        assert abs(math.remainder(result.pose[2] - pose[2], math.tau)) <= math.radians(1)
        assert result.matched and not result.lost


def test_a_loop_closure_may_correct_only_the_drift_since_the_last_one() -> None:
    """A closure moving a pose a closure anchored 1 m of path ago by a metre is an alias (the
    next shelf row), refused; after 20 m without a closure the same correction is taken."""
    mapper = Mapper(MapperConfig(loop_drift=(0.3, 0.1)))
    mapper._anchored_at = 50.0
    one_metre: Pose2 = (1.0, 0.0, 0.0)
    assert mapper._plausible((0.05, 0.02, math.radians(0.5)), 51.0)
    assert not mapper._plausible(one_metre, 51.0)
    assert mapper._plausible(one_metre, 70.0)
    assert not mapper._plausible((0.0, 0.0, math.radians(10)), 51.0)
