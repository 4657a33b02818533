# Collision monitor: footprints, the swept-path check and the stop/slowdown/approach/stale rules.
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from daemon.components.collision_monitor.component import horizon_warning
from daemon.components.collision_monitor.footprint import Footprint, FootprintError
from daemon.components.collision_monitor.monitor import CollisionMonitor, MonitorSettings
from daemon.components.collision_monitor.sweep import contact_travel

RECT = [[0.3, 0.2], [-0.3, 0.2], [-0.3, -0.2], [0.3, -0.2]]


def wall_points(x: float, y_from: float = -3.0, y_to: float = 3.0,
                step: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Points of a wall across the robot's path at ``x`` (robot frame)."""
    ys = np.arange(y_from, y_to + step / 2, step)
    return np.full_like(ys, x), ys


def monitor_with(px: np.ndarray, py: np.ndarray, **kw: object) -> CollisionMonitor:
    """A monitor that has seen one revolution (taken at t=0, robot at the origin)."""
    footprint = kw.pop("footprint", Footprint.circle(0.2))
    monitor = CollisionMonitor(MonitorSettings(footprint=footprint, **kw))  # type: ignore[arg-type]
    monitor.observe(0.0, 0.0, 0.0, 0.0)
    monitor.on_scan(px, py, 0.0, 0.1)
    return monitor


# -- footprints ---------------------------------------------------------------------------------

def test_circle_clearance_and_polygon_signed_distance() -> None:
    circle = Footprint.circle(0.2)
    assert circle.clearance(np.array([1.0]), np.array([0.0]))[0] == pytest.approx(0.8)
    rect = Footprint.from_points(RECT)
    got = rect.clearance(np.array([1.0, 0.0, 0.1]), np.array([0.0, 0.5, 0.0]))
    assert got == pytest.approx([0.7, 0.3, -0.2])  # ahead, beside, inside (negative)
    assert rect.reach == pytest.approx(math.hypot(0.3, 0.2))


def test_polygon_must_surround_the_origin() -> None:
    with pytest.raises(FootprintError, match="origin"):
        Footprint.from_points([[0.1, 0.1], [0.5, 0.1], [0.5, 0.5]])
    with pytest.raises(FootprintError, match="3"):
        Footprint.from_points([[0.1, 0.1], [0.5, 0.1]])


@given(x=st.floats(-0.3, 0.3), y=st.floats(-0.2, 0.2),
       corners=st.sampled_from([RECT, [[0.5, 0.1], [-0.2, 0.15], [-0.2, -0.15], [0.5, -0.1]],
                                [[0.1, 0.4], [-0.1, 0.4], [-0.1, -0.4], [0.1, -0.4]]]))
def test_covering_discs_cover_the_polygon(x: float, y: float,
                                          corners: list[list[float]]) -> None:
    footprint = Footprint.from_points(corners)
    if footprint.clearance(np.array([x]), np.array([y]))[0] > 0:
        return  # outside this polygon
    discs = footprint.discs
    assert (np.hypot(discs[:, 0] - x, discs[:, 1] - y) <= discs[:, 2] + 1e-9).any()


# -- the swept path -------------------------------------------------------------------------------

def distance_at(psi: float, px: float, py: float, disc: tuple[float, float, float],
                t: float) -> float:
    """How far the point is from the disc's centre after travel ``t`` along the arc."""
    v, w = math.cos(psi), math.sin(psi)
    cx, cy, _ = disc
    th = w * t
    x, y = (v / w * math.sin(th), v / w * (1 - math.cos(th))) if abs(w) > 1e-12 else (
        v * t, 0.0)
    return math.hypot(px - (x + cx * math.cos(th) - cy * math.sin(th)),
                      py - (y + cx * math.sin(th) + cy * math.cos(th)))


def brute_contact(psi: float, px: float, py: float, disc: tuple[float, float, float],
                  limit: float, dt: float = 2e-4) -> float | None:
    """Step the path and look for the first contact; None when the point starts inside and
    moves away (the monitor ignores it) or starts on the disc's edge (touching: the monitor
    may call it contact at once, the safe answer, or none)."""
    r = disc[2]
    start = distance_at(psi, px, py, disc, 0.0)
    if abs(start - r) < 1e-9:
        return None
    t = 0.0
    while t < limit:
        t += dt
        d = distance_at(psi, px, py, disc, t)
        if start < r:
            return 0.0 if d < start else None
        if d < r - 1e-9:  # grazing a point side-on (d == r) is no contact
            return t
    return math.inf


@settings(max_examples=60, deadline=None)
@given(psi=st.one_of(st.floats(-math.pi, math.pi), st.sampled_from([0.0, math.pi, 1.5708])),
       px=st.floats(-2, 2), py=st.floats(-2, 2), cx=st.floats(-0.2, 0.2),
       cy=st.floats(-0.1, 0.1), r=st.floats(0.15, 0.4))
@example(psi=1.0, px=0.0, py=0.25, cx=0.0, cy=0.0, r=0.25)  # starts on the edge (found by CI)
@example(psi=-0.001953125, px=0.0, py=0.25, cx=-0.00390625, cy=0.0, r=0.25)  # a graze
@example(psi=1.08e-07, px=1.0, py=0.0, cx=0.0, cy=0.0, r=0.25)  # an arc 9000 km across
def test_contact_travel_matches_a_stepped_sweep(psi: float, px: float, py: float, cx: float,
                                                 cy: float, r: float) -> None:
    got = contact_travel([psi], np.array([px]), np.array([py]), np.array([[cx, cy, r]]),
                         3.0)[0, 0, 0]
    expected = brute_contact(psi, px, py, (cx, cy, r), 3.0)
    if expected is None:
        return
    if math.isinf(expected):  # no contact, or a graze too shallow for the steps to see
        assert got == math.inf or got > 3.0 - 1e-3 or \
            distance_at(psi, px, py, (cx, cy, r), got) == pytest.approx(r, abs=1e-6)
    else:
        assert got == pytest.approx(expected, abs=2e-3)


# -- the rules ----------------------------------------------------------------------------------

def test_approach_limits_speed_to_stop_before_the_stop_zone() -> None:
    monitor = monitor_with(*wall_points(0.9))
    verdict = monitor.limit(2.0, 0.0, 2.0, 0.0, 0.05)
    # wall - footprint - stop margin - what 2 m/s covered since the last pose (0.05 s)
    room = 0.9 - 0.2 - 0.10 - 2.0 * 0.05
    a, reaction = 4.0, 0.12
    expected = a * (-reaction + math.sqrt(reaction ** 2 + 2 * room / a))
    assert verdict.action == "limit" and verdict.brake
    assert verdict.linear == pytest.approx(expected, rel=1e-6)
    assert verdict.angular == 0.0


def test_far_obstacles_beyond_the_projection_do_not_limit() -> None:
    monitor = monitor_with(*wall_points(2.5))
    assert monitor.limit(0.3, 0.0, 0.3, 0.0, 0.05).action == "none"  # 0.3 m/s x 1 s ahead


def test_stop_zone_blocks_motion_toward_it_but_not_away_or_turning() -> None:
    monitor = monitor_with(*wall_points(0.27))  # 0.07 m from the footprint
    toward = monitor.limit(0.5, 0.0, 0.0, 0.0, 0.05)
    assert (toward.linear, toward.action) == (0.0, "stop")
    assert monitor.zone(0.05) == "stop" and monitor.nearest() == pytest.approx(0.07)
    away = monitor.limit(-0.3, 0.0, 0.0, 0.0, 0.05)
    assert (away.linear, away.action) == (-0.3, "none")
    turn = monitor.limit(0.0, 1.0, 0.0, 0.0, 0.05)
    assert (turn.angular, turn.action) == (1.0, "none")  # a round robot turns in place freely
    arc_away = monitor.limit(-0.2, 0.5, 0.0, 0.0, 0.05)
    assert arc_away.action == "none"


def test_a_rectangle_cannot_swing_its_corners_into_a_wall() -> None:
    monitor = monitor_with(*wall_points(0.42), footprint=Footprint.from_points(RECT))
    assert monitor.limit(0.0, 1.0, 0.0, 0.0, 0.05).action in ("stop", "limit")
    assert monitor.limit(-0.2, 0.0, 0.0, 0.0, 0.05).action == "none"


def test_slowdown_zone_scales_motion_toward_the_obstacle() -> None:
    monitor = monitor_with(*wall_points(0.45))  # 0.25 m: slowdown (0.35), not stop (0.10)
    verdict = monitor.limit(0.1, 0.0, 0.1, 0.0, 0.05)
    assert verdict.action == "slowdown" and verdict.linear == pytest.approx(0.05)
    assert not verdict.brake
    assert monitor.limit(-0.1, 0.0, 0.0, 0.0, 0.05).linear == -0.1


def test_the_current_motion_is_checked_too() -> None:
    monitor = monitor_with(*wall_points(0.6))
    verdict = monitor.limit(-0.2, 0.0, 1.5, 0.0, 0.05)  # asking to back off, still at 1.5 m/s
    assert verdict.linear == -0.2 and verdict.brake and verdict.action == "limit"


def test_no_scan_or_a_stale_scan_stops() -> None:
    monitor = CollisionMonitor(MonitorSettings(footprint=Footprint.circle(0.2)))
    verdict = monitor.limit(0.5, 0.0, 0.0, 0.0, 0.0)
    assert (verdict.linear, verdict.action) == (0.0, "stop")
    assert "no lidar revolution" in verdict.reason
    monitor = monitor_with(np.array([]), np.array([]))  # a fresh scan of open space
    assert monitor.limit(0.5, 0.0, 0.0, 0.0, 0.3).action == "none"
    stale = monitor.limit(0.5, 0.0, 0.0, 0.0, 0.7)  # last ray at 0.1 s, timeout 0.5 s
    assert (stale.linear, stale.action) == (0.0, "stop") and "old" in stale.reason
    assert monitor.zone(0.7) == "unknown"


def test_stale_slowdown_still_respects_the_last_scan() -> None:
    monitor = monitor_with(*wall_points(0.27), stale_action="slowdown")
    assert monitor.limit(-0.4, 0.0, 0.0, 0.0, 1.0).linear == pytest.approx(-0.2)
    assert monitor.limit(0.4, 0.0, 0.0, 0.0, 1.0).action == "stop"


def test_distance_moved_since_the_scan_is_taken_off() -> None:
    monitor = monitor_with(*wall_points(1.0))
    assert monitor.limit(0.2, 0.0, 0.2, 0.0, 0.05).action == "none"
    monitor.observe(0.2, 0.75, 0.0, 0.0)  # odometry: 0.75 m further, no new revolution
    verdict = monitor.limit(0.2, 0.0, 0.2, 0.0, 0.2)
    assert verdict.action == "stop"  # 1.0 - 0.75 - 0.2 - 0.1 < 0: no room left


def test_a_revolution_is_placed_where_its_first_ray_was_taken() -> None:
    monitor = CollisionMonitor(MonitorSettings(footprint=Footprint.circle(0.2)))
    monitor.observe(0.0, 0.0, 0.0, 0.0)
    monitor.observe(0.3, 0.45, 0.0, 0.0)  # moved 0.45 m while the revolution was delivered
    monitor.on_scan(*wall_points(0.8), 0.0, 0.1)
    assert monitor.nearest() == pytest.approx(0.8 - 0.45 - 0.2)


def test_min_points_ignores_a_single_stray_return() -> None:
    px, py = np.array([0.25, 3.0]), np.array([0.0, 0.0])
    assert monitor_with(px, py).limit(0.3, 0.0, 0.0, 0.0, 0.05).action == "stop"
    assert monitor_with(px, py, min_points=2).limit(0.3, 0.0, 0.0, 0.0, 0.05).action == "none"


def test_horizon_warning_when_the_projection_is_too_short_to_stop() -> None:
    short = MonitorSettings(footprint=Footprint.circle(0.2), time_before_collision=0.2)
    assert "time_before_collision_s" in (horizon_warning(short) or "")
    assert horizon_warning(MonitorSettings(footprint=Footprint.circle(0.2))) is None
