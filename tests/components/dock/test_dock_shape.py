# The dock's V: world files, the charger contact, the fit to lidar points, the monitor's goal.
from __future__ import annotations

import math

import numpy as np
import pytest

from daemon.components.collision_monitor.footprint import Footprint
from daemon.components.collision_monitor.monitor import CollisionMonitor, MonitorSettings
from daemon.components.dock.approach import approach_twist
from nav.dock import DockShape, fit_v
from sim.settings import SimConfig
from sim.stepper import SimWorld
from sim.world import Pose, WorldError, load_world, world_from_dict
from slam.pose import between

SHAPE = DockShape()


def scan_at(world: SimWorld, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    world.reset(pose)
    ranges = world.scan()
    angles = np.arange(len(ranges)) * 2 * math.pi / len(ranges)
    return ranges * np.cos(angles), ranges * np.sin(angles)


@pytest.mark.parametrize("name", ["apartment", "warehouse"])
def test_the_built_in_worlds_have_a_dock_the_robot_fits_on(name: str) -> None:
    world = load_world(name)
    (dock,) = world.docks
    # docked, the footprint (0.2 m) stands clearance_m from the V's arms
    assert world.clearance(dock.x, dock.y) == pytest.approx(0.2 + SHAPE.clearance_m, abs=1e-3)
    assert world.docked(dock.x, dock.y, dock.theta)
    assert not world.docked(dock.x - 0.05 * math.cos(dock.theta), dock.y, dock.theta) or \
        not world.docked(dock.x, dock.y, dock.theta + 0.3)
    assert world_from_dict(world.to_dict()) == world


def test_world_file_docks_are_checked() -> None:
    base = {"arena": {"width": 4.0, "height": 4.0}}
    with pytest.raises(WorldError, match=r"docks\[0\]\.theta: missing"):
        world_from_dict({**base, "docks": [{"x": 0.0, "y": 1.0}]})
    with pytest.raises(WorldError, match=r"docks\[0\]\.x: must be finite"):
        world_from_dict({**base, "docks": [{"x": math.nan, "y": 1.0, "theta": 0.0}]})
    with pytest.raises(WorldError, match="docks: expected a list"):
        world_from_dict({**base, "docks": {"x": 1}})


def test_the_pack_charges_only_on_the_dock() -> None:
    world = SimWorld(SimConfig.from_section({"world_file": "apartment", "noise": False,
                                             "battery_charge": 0.5}))
    dock = world.world.docks[0]
    world.advance(1.0)
    assert not world.on_charger() and world.battery.measure()[1] > 0  # discharging
    world.reset(dock)
    world.advance(1.0)
    assert world.on_charger() and world.battery.measure()[1] < 0  # charging


@pytest.mark.parametrize("noise", [False, True])
def test_the_v_is_found_where_it_is(noise: bool) -> None:
    world = SimWorld(SimConfig.from_section({"world_file": "warehouse", "noise": noise}))
    dock = world.world.docks[0]
    true = (dock.x, dock.y, dock.theta)
    rng = np.random.default_rng(3)
    errors = []
    for _ in range(30):
        back, side, turn = rng.uniform(0.0, 0.7), rng.uniform(-0.1, 0.1), rng.uniform(-0.2, 0.2)
        pose = Pose(dock.x - back, dock.y + side, turn)
        px, py = scan_at(world, pose)
        truth = between((pose.x, pose.y, pose.theta), true)
        guess = (truth[0] + rng.uniform(-0.15, 0.15), truth[1] + rng.uniform(-0.15, 0.15),
                 truth[2] + rng.uniform(-0.15, 0.15))
        fit = fit_v(px, py, guess, SHAPE)
        assert fit is not None
        off = between(truth, fit.docked)
        errors.append((math.hypot(off[0], off[1]), abs(off[2])))
    worst_m, worst_rad = np.max(errors, axis=0)
    mean_m, mean_rad = np.mean(errors, axis=0)
    if noise:  # one revolution (sigma 0.02 m a ray); the approach averages many
        assert mean_m < 0.015 and mean_rad < math.radians(3.0)
    else:
        assert worst_m < 0.002 and worst_rad < math.radians(0.2)


def test_no_v_no_fit() -> None:
    world = SimWorld(SimConfig.from_section({"world_file": "warehouse", "noise": False}))
    px, py = scan_at(world, Pose(7.0, 3.0, 0.0))  # the loading area, the dock 4 m away
    assert fit_v(px, py, (0.5, 0.0, 0.0), SHAPE) is None
    assert fit_v(np.array([]), np.array([]), (0.5, 0.0, 0.0), SHAPE) is None


def test_the_monitor_lets_the_robot_touch_only_the_goal() -> None:
    monitor = CollisionMonitor(MonitorSettings(footprint=Footprint.circle(0.2)))
    monitor.observe(0.0, 0.0, 0.0, 0.0)
    arms = SHAPE.arms((0.15, 0.0, 0.0))  # the robot stands 0.15 m short of the dock
    points = np.concatenate([np.linspace((x1, y1), (x2, y2), 30) for x1, y1, x2, y2 in arms])
    monitor.on_scan(points[:, 0], points[:, 1], 0.0, 0.0)
    assert monitor.limit(0.05, 0.0, 0.0, 0.0, 0.01).action != "none"
    monitor.set_goal_zone(arms, 0.05)
    assert monitor.limit(0.05, 0.0, 0.0, 0.0, 0.02).linear == pytest.approx(0.05)
    assert monitor.goal_points == len(points)
    # anything else in the way still stops it: a leg between the arms
    leg = np.array([[0.28, 0.0]])
    both = np.concatenate([points, leg])
    monitor.on_scan(both[:, 0], both[:, 1], 0.03, 0.03)
    assert monitor.limit(0.05, 0.0, 0.0, 0.0, 0.04).action == "stop"
    monitor.set_goal_zone(None)
    monitor.on_scan(points[:, 0], points[:, 1], 0.05, 0.05)
    assert monitor.limit(0.05, 0.0, 0.0, 0.0, 0.06).action != "none"


def test_the_approach_steers_onto_the_axis_and_stops_on_the_dock() -> None:
    docked = (1.0, 0.0, 0.0)
    v, w, left = approach_twist((0.4, 0.03, 0.0), docked, 0.1)
    assert v > 0 and w < 0 and left == pytest.approx(0.6)  # left of the axis: turns right
    v, w, _ = approach_twist((0.4, 0.0, 1.0), docked, 0.1)
    assert v == 0 and w < 0  # far off heading: turns first
    assert approach_twist((1.0, 0.0, 0.0), docked, 0.1)[:2] == (0.0, 0.0)
