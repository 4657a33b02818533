# The built-in worlds that need a map (apartment, warehouse, corridor loop): they load by name,
# start in free space, every room and aisle is reachable, and the lidar sees walls from the start.
from __future__ import annotations

import json
import math
import subprocess
import sys
from importlib import resources

import numpy as np
import pytest

from sim.coverage import Coverage
from sim.mapping_truth import dilate, reachable_free_cells, world_grid
from sim.raycast import RayCaster, ray_angles
from sim.settings import SimConfig, SimConfigError
from sim.stepper import SimWorld, build_world
from sim.world import Segment, World, WorldError, builtin_worlds, load_world
from tests.support.paths import REPO

FOOTPRINT = SimConfig.from_section().footprint_radius
RES = 0.05

#: (width, height) of each world's bounding box (m)
SIZES = {"apartment": (10.0, 8.0), "warehouse": (20.0, 20.0), "loop": (14.0, 10.5)}

#: a point in every room, aisle or corridor side of each world
PLACES = {
    "apartment": {"living room": (-3.0, -0.5), "kitchen": (3.0, -2.5),
                  "bedroom 1": (-2.5, 1.6), "bathroom": (-0.5, 2.2), "bedroom 2": (2.2, 1.8),
                  "bedroom 2 beside the bed": (2.3, 3.5), "behind the island": (3.0, 0.2)},
    "warehouse": {**{f"aisle y={y}": (0.0, y) for y in (-7.5, -4.5, -1.5, 1.5, 4.5, 7.5)},
                  "left aisle": (-9.0, 0.0), "cross aisle": (-1.75, 0.0),
                  "between the pillars": (-1.75, 8.5), "loading area": (8.0, -6.0),
                  "office": (7.5, 8.5)},
    "loop": {"bottom": (0.0, -4.0), "right": (6.0, 0.0), "top": (0.0, 4.0),
             "left": (-6.0, 0.0), "a niche": (7.0, 1.0)},
}

#: the narrowest passage each world promises (m): a footprint this wide still gets everywhere
NARROWEST = {"apartment": 0.9, "warehouse": 1.2, "loop": 1.1}  # loop: 1.15 m by a bin
#: places a footprint of NARROWEST is not meant to reach (a 1 m office door, the niches)
NOT_FOR_WIDE = {"warehouse": {"office"}, "loop": {"a niche"}}


def test_the_three_worlds_are_built_in_and_ship_as_package_data() -> None:
    assert builtin_worlds() == ("apartment", "loop", "warehouse")
    shipped = {f.name for f in resources.files("sim.worlds").iterdir()}
    assert {"apartment.toml", "loop.toml", "warehouse.toml"} <= shipped


@pytest.mark.parametrize("name", sorted(SIZES))
def test_a_world_loads_by_name_at_its_size(name: str) -> None:
    world = load_world(name)
    grid = world_grid(world, RES)
    width, height = SIZES[name]
    assert grid.width * RES == pytest.approx(width, abs=RES)
    assert grid.height * RES == pytest.approx(height, abs=RES)
    assert build_world(SimConfig.from_section({"world_file": name})) == world


@pytest.mark.parametrize("name", sorted(SIZES))
def test_the_start_pose_is_free_for_the_footprint(name: str) -> None:
    world = load_world(name)
    assert world.clearance(world.start.x, world.start.y) > FOOTPRINT + 0.3
    sim = SimWorld(SimConfig.from_section({"world_file": name}))
    truth = sim.ground_truth()
    assert (truth.x, truth.y, truth.theta) == (world.start.x, world.start.y, world.start.theta)


@pytest.mark.parametrize("name", sorted(SIZES))
def test_every_room_and_aisle_is_reachable(name: str) -> None:
    world = load_world(name)
    grid = world_grid(world, RES)
    reached = reachable_free_cells(world, RES, FOOTPRINT, grid=grid)
    missing = [place for place, (x, y) in PLACES[name].items() if not reached[grid.cell_of(x, y)]]
    assert missing == []
    # the passages are as wide as promised: a footprint of that diameter gets there too
    wide = reachable_free_cells(world, RES, NARROWEST[name] / 2 - 0.01, grid=grid)
    skipped = NOT_FOR_WIDE.get(name, set())
    missing = [place for place, (x, y) in PLACES[name].items()
               if place not in skipped and not wide[grid.cell_of(x, y)]]
    assert missing == []


def test_the_loop_closes_on_itself_and_is_40_m_round() -> None:
    world = load_world("loop")
    grid = world_grid(world, RES)
    cut = World((*world.segments, Segment(0.5, -5.0, 0.5, -3.0)), world.circles, world.start)
    reached = reachable_free_cells(cut, RES, FOOTPRINT, grid=grid)
    # cut just ahead of the start, the far side of the cut is still reached: the other way round
    assert reached[grid.cell_of(1.5, -4.0)]
    block = world.segments[:4]  # the inner block comes first in loop.toml
    half_x = max(max(abs(s.x1), abs(s.x2)) for s in block)
    half_y = max(max(abs(s.y1), abs(s.y2)) for s in block)
    centre_line = 2 * ((2 * half_x + 1.5) + (2 * half_y + 1.5))  # 0.75 m off the block
    assert centre_line == pytest.approx(40.0)
    assert world.clearance(0.0, -4.0) == pytest.approx(0.75)  # 1.5 m wide


@pytest.mark.parametrize("name", sorted(SIZES))
def test_the_lidar_sees_walls_from_the_start(name: str) -> None:
    world = load_world(name)
    ranges = RayCaster(world, ray_angles(360)).cast(world.start.x, world.start.y,
                                                    world.start.theta)
    assert np.isfinite(ranges).mean() > 0.8  # the warehouse is larger than the 10 m range
    assert ranges[np.isfinite(ranges)].min() > FOOTPRINT


@pytest.mark.parametrize("name", sorted(SIZES))
def test_coverage_counts_only_the_reachable_free_area(name: str) -> None:
    world = load_world(name)
    coverage = Coverage(world, FOOTPRINT)
    centres = [(coverage.x0 + (i + 0.5) * coverage.cell, coverage.y0 + (j + 0.5) * coverage.cell)
               for j in range(coverage.ny) for i in range(coverage.nx)]
    free = np.array([world.clearance(x, y) > FOOTPRINT for x, y in centres])
    assert coverage.free_cells < free.sum()  # shelves, furniture or the loop's block
    grid = world_grid(world, RES)
    reached = dilate(reachable_free_cells(world, RES, FOOTPRINT, grid=grid), 1)
    in_reach = np.array([reached[grid.cell_of(x, y)] for x, y in centres])
    assert np.array_equal(coverage.free, free & in_reach)


def test_an_unknown_world_name_is_refused_naming_the_worlds() -> None:
    with pytest.raises(WorldError, match=r"unknown world 'flat'.*apartment, loop, warehouse"):
        load_world("flat")
    with pytest.raises(SimConfigError, match=r"\[sim\] world_file: unknown world 'flat'"):
        SimConfig.from_section({"world_file": "flat"})


def test_simulate_takes_a_world_by_name() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "daemon.cli", "simulate", "--seconds", "2", "--world",
         "apartment", "--json"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    run = json.loads(result.stdout)
    assert run["world"] == "apartment" and run["collisions"] == 0
    start = load_world("apartment").start
    assert math.hypot(run["final"]["x"] - start.x, run["final"]["y"] - start.y) < 1e-6
    bad = subprocess.run([sys.executable, "-m", "daemon.cli", "simulate", "--seconds", "1",
                          "--world", "flat"], cwd=REPO, capture_output=True, text=True,
                         timeout=300)
    assert bad.returncode == 78 and "unknown world 'flat'" in bad.stderr
