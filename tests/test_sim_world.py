# Tests of the simulated arena: seeded obstacle placement and world files.
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from sim.world import (
    Circle,
    Pose,
    Segment,
    World,
    WorldError,
    arena_walls,
    generated_world,
    load_world,
    world_from_dict,
)

FOOTPRINT = 0.2


def _check_world(world: World, start: Pose, clearance: float) -> None:
    assert len(world.segments) == 4
    assert len(world.circles) == 8
    for i, c in enumerate(world.circles):
        assert 0.3 <= c.r <= 0.6
        assert abs(c.x) + c.r < 8.0 and abs(c.y) + c.r < 8.0
        assert math.hypot(c.x - start.x, c.y - start.y) - c.r >= clearance
        for other in world.circles[i + 1:]:
            assert math.hypot(c.x - other.x, c.y - other.y) > c.r + other.r
    assert world.clearance(start.x, start.y) > FOOTPRINT


def test_obstacles_never_overlap_the_start_pose() -> None:
    for seed in range(500):
        _check_world(generated_world(seed), Pose(), 1.5)


def test_obstacles_keep_clear_of_an_off_centre_start() -> None:
    start = Pose(-6.5, 5.0, 1.0)
    for seed in range(100):
        world = generated_world(seed, start=start, start_clearance=0.5)
        _check_world(world, start, 0.5)
        assert world.start == start


def test_same_seed_same_world_other_seed_other_world() -> None:
    assert generated_world(7) == generated_world(7)
    assert generated_world(7).circles != generated_world(8).circles


def test_arena_is_16_m_square_centred_on_origin() -> None:
    walls = arena_walls(16.0, 16.0)
    xs = {v for s in walls for v in (s.x1, s.x2)}
    ys = {v for s in walls for v in (s.y1, s.y2)}
    assert xs == {-8.0, 8.0} and ys == {-8.0, 8.0}
    assert generated_world(1).clearance(0.0, 0.0) <= 8.0


def test_impossible_placement_is_an_error() -> None:
    with pytest.raises(WorldError, match="could not place 200 obstacles"):
        generated_world(1, size=6.0, obstacles=200, max_tries=2000)
    with pytest.raises(WorldError, match="outside"):
        generated_world(1, start=Pose(9.0, 0.0))
    with pytest.raises(WorldError, match="radii"):
        generated_world(1, radius_min=0.6, radius_max=0.3)


def test_clearance_is_distance_to_nearest_surface() -> None:
    world = World(arena_walls(16, 16), (Circle(3.0, 0.0, 0.5),))
    assert world.clearance(0.0, 0.0) == pytest.approx(2.5)
    assert world.clearance(7.0, 7.5) == pytest.approx(0.5)
    assert world.clearance(-7.9, 0.0) == pytest.approx(0.1)


TOML_WORLD = """
[arena]
width = 10
height = 6

[start]
x = -3.0
y = 0.5
theta = 1.5707963

[[walls]]
from = [0.0, -3.0]
to = [0.0, 1.0]

[[circles]]
center = [2.0, 1.5]
radius = 0.4
"""


def test_load_toml_and_json_give_the_same_world(tmp_path: Path) -> None:
    toml_path = tmp_path / "room.toml"
    toml_path.write_text(TOML_WORLD)
    world = load_world(toml_path)
    assert world.segments[:4] == arena_walls(10, 6)
    assert world.segments[4] == Segment(0.0, -3.0, 0.0, 1.0)
    assert world.circles == (Circle(2.0, 1.5, 0.4),)
    assert world.start == Pose(-3.0, 0.5, 1.5707963)
    json_path = tmp_path / "room.json"
    json_path.write_text(json.dumps(world.to_dict()))
    assert load_world(json_path) == world


def test_world_round_trips_through_its_dict() -> None:
    world = generated_world(3)
    assert world_from_dict(world.to_dict()) == world


@pytest.mark.parametrize(("data", "message"), [
    ({"walls": [], "circle": []}, "unknown field 'circle'"),
    ({"circles": [{"center": [1, 2]}]}, r"circles\[0\]\.radius: missing"),
    ({"circles": [{"center": [1, 2], "radius": -1}]}, r"circles\[0\]\.radius: must be > 0"),
    ({"circles": [{"center": [1, "a"], "radius": 1}]}, r"circles\[0\]\.center\[1\]: expected a"),
    ({"walls": [{"from": [0, 0], "to": [0, 0]}]}, r"walls\[0\]: a wall needs two different"),
    ({"walls": [{"from": [0, 0], "to": [1, 0], "color": 1}]}, r"unknown field 'walls\[0\]\.color'"),
    ({"walls": {"from": [0, 0]}}, "walls: expected a list"),
    ({"arena": {"width": 0, "height": 4}}, "arena: width and height must be > 0"),
    ({}, "no walls and no circles"),
    ({"circles": [{"center": [0, 0], "radius": 1}]}, "start: .* inside or on an obstacle"),
    ({"arena": {"width": 4, "height": 4}, "start": {"x": 0}}, r"start\.y: missing"),
])
def test_bad_world_data_names_the_field(data: dict[str, object], message: str) -> None:
    with pytest.raises(WorldError, match=message):
        world_from_dict(data)


@pytest.mark.parametrize(("name", "content", "message"), [
    ("none.toml", None, r"none\.toml: cannot read"),
    ("room.yaml", "walls: []", r"room.yaml: world files must end in \.toml or \.json"),
    ("broken.json", "{\"walls\": [", r"broken\.json: not valid JSON"),
    ("unknown.toml", "[arena]\nwidth = 4\nheight = 4\ndepth = 2\n",
     r"unknown\.toml: unknown field 'arena\.depth'"),
])
def test_bad_world_files_name_the_file(tmp_path: Path, name: str, content: str | None,
                                       message: str) -> None:
    path = tmp_path / name
    if content is not None:
        path.write_text(content)
    with pytest.raises(WorldError, match=message):
        load_world(path)


def test_nearby_lists_what_is_within_reach() -> None:
    world = World(arena_walls(16, 16), (Circle(3.0, 0.0, 0.5), Circle(-5.0, 0.0, 0.5)))
    circles, segments = world.nearby(7.0, 0.0, 1.2)
    assert circles == () and segments == (world.segments[1],)  # the right wall, 1 m away
    circles, segments = world.nearby(2.0, 0.0, 0.6)
    assert circles == (world.circles[0],) and segments == ()
