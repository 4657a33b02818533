# The map composed from rigid submaps: it matches a full re-render, and a correction costs only
# the submaps it moved.
from __future__ import annotations

import math

import numpy as np

from slam.grid import OccupancyGrid
from slam.mapper import Mapper, MapperConfig
from slam.pose import Pose2, compose
from slam.submaps import SubmapAtlas
from tests.slam_room import cast

START: Pose2 = (1.0, 1.0, 0.0)


def _path(count: int) -> list[Pose2]:
    poses, pose = [], START
    for i in range(count):
        pose = compose(pose, (0.3, 0.0, 0.25 if i % 8 < 4 else -0.1))
        poses.append((min(max(pose[0], 0.6), 7.4), min(max(pose[1], 0.6), 3.4), pose[2]))
    return poses


def _atlas(poses: list[Pose2], per: int = 5) -> tuple[SubmapAtlas, np.ndarray, list[np.ndarray]]:
    atlas = SubmapAtlas(0.05, 4_000_000, per)
    points = [cast(p) for p in poses]
    array = np.asarray(poses, dtype=np.float64)
    for k, pose in enumerate(poses):
        anchor = atlas.anchor_key()
        atlas.add_key(k, pose, None if anchor is None else tuple(array[anchor]), points[k])
    atlas.compose(array, points.__getitem__)
    return atlas, array, points


def _occupied(grid: OccupancyGrid) -> set[tuple[int, int]]:
    xy = grid.occupied_points()
    return {(round(x / 0.05), round(y / 0.05)) for x, y in xy}


def test_composed_map_matches_integrating_every_key_scan() -> None:
    poses = _path(24)
    atlas, _, points = _atlas(poses)
    whole = OccupancyGrid(0.05)
    for pose, pts in zip(poses, points, strict=True):
        whole.integrate(pose, pts)
    composed, direct = _occupied(atlas.grid()), _occupied(whole)
    near = {(c + dc, r + dr) for c, r in direct for dc in (-1, 0, 1) for dr in (-1, 0, 1)}
    assert len(composed & near) >= 0.97 * len(composed)
    assert len(composed) >= 0.8 * len(direct)
    known = atlas.grid().occupancy() >= 0
    assert known.sum() > 0.8 * (whole.occupancy() >= 0).sum()


def test_a_correction_moves_only_the_submaps_it_moved() -> None:
    atlas, poses, points = _atlas(_path(20))
    before = atlas.grid()
    atlas.compose(poses, points.__getitem__)
    assert atlas.last_placed == 0 and atlas.grid() is before  # nothing moved: nothing redone
    moved = poses.copy()
    moved[15:20, 0] += 0.4  # the last submap (keys 15..19) shifted rigidly
    atlas.compose(moved, points.__getitem__)
    assert (atlas.last_placed, atlas.last_rebuilt) == (1, 0)
    after = atlas.grid()
    assert after.version > before.version
    bent = moved.copy()
    bent[7, 1] += 0.2  # one key scan of the second submap moved relative to its anchor
    atlas.compose(bent, points.__getitem__)
    assert (atlas.last_placed, atlas.last_rebuilt) == (1, 1)


def test_moving_a_submap_away_and_back_restores_the_sum_exactly() -> None:
    atlas, poses, points = _atlas(_path(10))
    total, seen = atlas.total.log_odds.copy(), atlas.seen.copy()
    moved = poses.copy()
    turn: Pose2 = (3.0, -1.0, math.radians(20))  # the second submap turned and moved rigidly
    moved[5:] = [compose(turn, tuple(p)) for p in poses[5:]]
    atlas.compose(moved, points.__getitem__)
    atlas.compose(poses, points.__getitem__)
    assert atlas.last_rebuilt == 0
    assert int(atlas.seen.sum()) == int(seen.sum())
    assert math.isclose(float(np.abs(atlas.total.log_odds).sum()),
                        float(np.abs(total).sum()), rel_tol=1e-5)
    assert not (atlas.total.log_odds[atlas.seen == 0]).any()


def test_the_mapper_renders_its_map_from_submaps_after_loop_closures() -> None:
    mapper = Mapper(MapperConfig(keys_per_submap=5, loop_min_travel=4.0), initial_pose=START)
    truth: Pose2 = START
    odom: Pose2 = (0.0, 0.0, 0.0)
    for i in range(120):
        step = (0.06, 0.0, 0.05 if (i // 30) % 2 == 0 else -0.05)
        truth = compose(truth, step)
        odom = compose(odom, (step[0] * 1.04, 0.0, step[2] * 1.03))
        mapper.add_scan(odom, cast(truth), 0.1 * i)
        if i % 10 == 0:
            assert mapper.grid.width > 0
    health = mapper.health()
    assert health["submaps"] >= 2 and health["key_scans"] > 5
    assert mapper.grid.occupancy().max() == 100


def test_composing_after_every_key_scan_gives_the_sum_of_one_compose_at_the_end() -> None:
    """The active submap is placed, then grows: it is taken out as it was before it changes."""
    poses = _path(17)
    array = np.asarray(poses, dtype=np.float64)
    points = [cast(p) for p in poses]
    often = SubmapAtlas(0.05, 4_000_000, 5)
    for k, pose in enumerate(poses):
        anchor = often.anchor_key()
        often.add_key(k, pose, None if anchor is None else tuple(array[anchor]), points[k])
        often.compose(array[:k + 1], points.__getitem__)
    once, _, _ = _atlas(poses)
    a, b = often.grid(), once.grid()  # the sums grew differently; the maps are cropped
    assert (a.origin_x, a.origin_y) == (b.origin_x, b.origin_y)
    assert int(often.seen.sum()) == int(once.seen.sum())
    occ_a, occ_b = a.occupancy(), b.occupancy()
    assert np.array_equal(occ_a == -1, occ_b == -1)  # float residues of +/- only round
    assert np.abs(occ_a.astype(int) - occ_b.astype(int)).max() <= 1
