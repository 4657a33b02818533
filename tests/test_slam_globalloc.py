# Global localisation: a scan found anywhere on a map with no pose given, "ambiguous" rather than
# a confident wrong pose where places look alike, and a moved robot noticed and found again.
from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from slam.field import DistanceField
from slam.globalloc import AMBIGUOUS, FOUND, GlobalLocalizer
from slam.grid import OccupancyGrid
from slam.mapper import Mapper, MapperConfig
from slam.pose import Pose2
from tests.slam_room import ROOM, cast
from tests.support.paths import REPO

#: a plain 8 x 4 m rectangle: every pose has its twin turned half a turn about the centre
BOX = np.array([[0, 0, 8, 0], [8, 0, 8, 4], [8, 4, 0, 4], [0, 4, 0, 0]], dtype=np.float64)


def _map(walls: np.ndarray) -> OccupancyGrid:
    grid = OccupancyGrid(0.05, initial_size=12.0)
    for x in np.arange(0.6, 7.5, 0.7):
        for y in np.arange(0.6, 3.5, 0.7):
            pose = (float(x), float(y), 0.0)
            grid.integrate(pose, cast(pose, walls=walls))
    return grid


def _error(a: Pose2, b: Pose2) -> tuple[float, float]:
    return math.hypot(a[0] - b[0], a[1] - b[1]), abs(math.remainder(a[2] - b[2], math.tau))


@pytest.fixture(scope="module")
def room() -> OccupancyGrid:
    return _map(ROOM)


@pytest.mark.parametrize("truth", [(1.3, 1.1, 0.4), (6.8, 3.1, -2.0), (3.9, 3.2, 2.9),
                                   (7.2, 0.6, 1.2)])
def test_a_scan_is_found_on_the_whole_map_without_a_pose(room: OccupancyGrid,
                                                         truth: Pose2) -> None:
    localizer = GlobalLocalizer(room, DistanceField.from_grid(room, 0.5))
    result = localizer.search(cast(truth))
    assert result.status == FOUND and result.pose is not None, result
    error, turn = _error(result.pose, truth)
    assert error <= 0.1 and turn <= math.radians(5)


def test_a_symmetric_place_is_ambiguous_not_confidently_wrong() -> None:
    box = _map(BOX)
    localizer = GlobalLocalizer(box, DistanceField.from_grid(box, 0.5))
    truth = (2.0, 1.5, 0.3)
    result = localizer.search(cast(truth, walls=BOX))
    assert result.status == AMBIGUOUS and result.pose is None
    twin = (8.0 - truth[0], 4.0 - truth[1], truth[2] - math.pi)
    poses = [pose for pose, _ in result.candidates]
    assert any(_error(p, truth)[0] < 0.15 for p in poses)
    assert any(_error(p, twin)[0] < 0.15 for p in poses)


def test_no_scan_or_a_scan_of_nothing_is_not_found(room: OccupancyGrid) -> None:
    localizer = GlobalLocalizer(room, DistanceField.from_grid(room, 0.5))
    assert localizer.search(np.zeros((0, 2))).status == "not_found"
    rng = np.random.default_rng(3)
    noise = localizer.search(rng.uniform(-6, 6, (360, 2)))
    assert noise.status in ("not_found", "ambiguous") and noise.pose is None


def test_the_mapper_finds_its_pose_then_notices_a_carry_and_finds_it_again(
        room: OccupancyGrid) -> None:
    mapper = Mapper(MapperConfig(mode="localize", lost_after=3), grid=room)
    mapper.find_pose()
    here = (1.5, 1.0, 0.2)
    first = mapper.add_scan((0.0, 0.0, 0.0), cast(here), 0.0)
    assert first.status == "tracking" and _error(first.pose, here)[0] < 0.1
    assert all(mapper.add_scan((0.0, 0.0, 0.0), cast(here), 0.1 * i).matched
               for i in range(1, 5))
    carried = (6.6, 2.2, -1.8)  # picked up and put down elsewhere: odometry saw nothing
    statuses = [mapper.add_scan((0.0, 0.0, 0.0), cast(carried), 0.5 + 0.1 * i).status
                for i in range(6)]
    assert "lost" in statuses and statuses[-1] == "tracking", statuses
    assert _error(mapper.add_scan((0.0, 0.0, 0.0), cast(carried), 1.2).pose, carried)[0] < 0.1
    assert mapper.global_searches >= 2 and mapper.kidnaps == 1


def test_ambiguous_places_are_followed_until_one_fits() -> None:
    """A box with one stub: from the middle both halves fit; driving to the stub decides."""
    walls = np.vstack([BOX, [[7.0, 0.0, 7.0, 0.8]]])
    grid = _map(walls)
    mapper = Mapper(MapperConfig(mode="localize"), grid=grid)
    mapper.find_pose()
    start: Pose2 = (3.0, 2.0, 0.0)
    results = []
    for i in range(30):
        truth = (start[0] + 0.1 * i, start[1], 0.0)
        results.append(mapper.add_scan((0.1 * i, 0.0, 0.0), cast(truth, walls=walls), 0.1 * i))
        if results[-1].status == "tracking":
            break
    statuses = [r.status for r in results]
    assert statuses[-1] == "tracking", statuses
    assert _error(results[-1].pose, truth)[0] < 0.1
    assert all(s in ("ambiguous", "tracking") for s in statuses)


def test_simulate_localise_prints_the_summary_last() -> None:
    result = subprocess.run([sys.executable, "-m", "daemon.cli", "simulate", "--localise", "2",
                             "--world", "apartment", "--seed", "4", "--json"], cwd=REPO,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    last = json.loads(result.stdout.strip().splitlines()[-1])
    assert last["trials"] == 2 and last["found"] + last["ambiguous"] + last["wrong"] + \
        last["not_found"] == 2
    assert last["wrong"] == 0 and last["median_s"] is not None
    kidnap = subprocess.run([sys.executable, "-m", "daemon.cli", "simulate", "--localise", "2",
                             "--kidnap", "--world", "apartment", "--json"], cwd=REPO,
                            capture_output=True, text=True, timeout=300)
    assert kidnap.returncode == 0, kidnap.stderr
    summary = json.loads(kidnap.stdout.strip().splitlines()[-1])
    assert summary["trials"] == 2 and summary["noticed"] == 2 and summary["wrong"] == 0
    bad = subprocess.run([sys.executable, "-m", "daemon.cli", "simulate", "--localise", "0"],
                         cwd=REPO, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--localise" in bad.stderr


def test_a_carry_to_a_look_alike_place_is_caught_by_the_periodic_whole_map_check() -> None:
    walls = np.vstack([BOX, [[7.0, 0.0, 7.0, 0.8]]])
    mapper = Mapper(MapperConfig(mode="localize", global_check_every=5), grid=_map(walls))
    here: Pose2 = (2.0, 2.0, 0.0)
    mapper.set_pose(here, (0.0, 0.0, 0.0))
    for i in range(3):
        assert mapper.add_scan((0.0, 0.0, 0.0), cast(here, walls=walls), 0.1 * i).matched
    twin: Pose2 = (6.0, 2.0, math.pi)  # half a turn about the centre: only the stub differs
    results = [mapper.add_scan((0.0, 0.0, 0.0), cast(twin, walls=walls), 1.0 + 0.1 * i)
               for i in range(40)]
    assert mapper.kidnaps == 1, [r.status for r in results]
    assert results[-1].status == "tracking" and _error(results[-1].pose, twin)[0] < 0.1
