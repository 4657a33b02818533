# Regulated Pure Pursuit: follows a path with speeds cut on curves, near obstacles and at the end.
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

Pose = tuple[float, float, float]
#: path points looked at at once for the carrot
LOOKAHEAD_WINDOW = 64
#: a path turning by more than this at a point bends there (rad)
BEND_RAD = 1e-6


@dataclass(frozen=True)
class PursuitSettings:
    """The controller's limits and gains (m, s, rad)."""

    max_speed: float = 0.5
    max_turn: float = 1.5
    max_deceleration: float = 0.5
    lookahead_time: float = 1.5
    min_lookahead: float = 0.3
    max_lookahead: float = 1.0
    #: below this turning radius the speed is cut in proportion (m)
    min_radius: float = 0.9
    #: slowest approach speed while the goal is not reached (m/s)
    min_approach_speed: float = 0.05
    #: the carrot is pulled back along the path until the straight line to it passes every
    #: path point before it within this (plus the robot's own distance from the path; m): at
    #: a corner the robot turns at the corner instead of cutting it (0: pure look-ahead)
    corridor: float = 0.05
    #: turn in place first when the path's direction is further off than this (rad)
    rotate_first: float = 0.8
    #: heading gain when turning in place (1/s)
    turn_gain: float = 2.5
    #: slowest turn in place while the heading is not reached (rad/s)
    min_turn: float = 0.15
    xy_tolerance: float = 0.05
    yaw_tolerance: float = 0.05


@dataclass
class Command:
    """What the controller asks for: speeds, and where it stands."""

    v: float
    w: float
    phase: str  # rotate | follow | align | arrived
    remaining_m: float
    cross_track_m: float


class Pursuit:
    """Follows one path ((N, 2) points, start to goal) ending in ``goal_yaw`` (None: any
    heading). :meth:`step` takes the pose and the current speed and returns a command; it keeps
    the index of the nearest point so progress only goes forward."""

    def __init__(self, settings: PursuitSettings, path: np.ndarray, goal_yaw: float | None,
                 *, loop: bool = False) -> None:
        self.settings = settings
        self.path = np.asarray(path, dtype=float)
        self.goal_yaw = goal_yaw
        self.loop = loop
        steps = np.hypot(*np.diff(self.path, axis=0).T) if len(self.path) > 1 else np.zeros(0)
        self.along = np.concatenate(([0.0], np.cumsum(steps)))
        self.bends = bends(self.path, loop)
        self.nearest = 0
        self.arrived = False

    @property
    def length(self) -> float:
        return float(self.along[-1])

    def step(self, pose: Pose, speed: float) -> Command:
        x, y, theta = pose
        s = self.settings
        cross = self._advance(x, y)
        goal = self.path[-1]
        to_goal = math.hypot(goal[0] - x, goal[1] - y)
        remaining = float(self.along[-1] - self.along[self.nearest]) + \
            (0.0 if self.nearest < len(self.path) - 1 else to_goal)
        if not self.loop and (self.arrived or (to_goal <= s.xy_tolerance
                                               and self.nearest >= len(self.path) - 2)):
            self.arrived = True
            return self._align(theta, remaining, cross)
        lookahead = min(max(abs(speed) * s.lookahead_time, s.min_lookahead), s.max_lookahead)
        tx, ty = self._carrot(x, y, lookahead, cross)
        dx, dy = tx - x, ty - y
        local_x = math.cos(theta) * dx + math.sin(theta) * dy
        local_y = -math.sin(theta) * dx + math.cos(theta) * dy
        bearing = math.atan2(local_y, local_x)
        if abs(bearing) > s.rotate_first and to_goal > s.xy_tolerance:
            return Command(0.0, self._turn(bearing), "rotate", remaining, cross)
        distance_sq = max(local_x * local_x + local_y * local_y, 1e-9)
        curvature = 2.0 * local_y / distance_sq
        v = self._regulated_speed(curvature, remaining)
        w = max(-s.max_turn, min(s.max_turn, v * curvature))
        if abs(v * curvature) > s.max_turn:
            v = s.max_turn / abs(curvature)
        return Command(v, w, "follow", remaining, cross)

    def _regulated_speed(self, curvature: float, remaining: float) -> float:
        s = self.settings
        v = s.max_speed
        if abs(curvature) > 1e-9 and 1.0 / abs(curvature) < s.min_radius:
            v *= (1.0 / abs(curvature)) / s.min_radius
        if not self.loop:  # stop at the goal: v^2 = 2 a d
            v = min(v, math.sqrt(2.0 * s.max_deceleration * max(remaining, 0.0)))
        return max(v, s.min_approach_speed)

    def _align(self, theta: float, remaining: float, cross: float) -> Command:
        s = self.settings
        if self.goal_yaw is None:
            return Command(0.0, 0.0, "arrived", remaining, cross)
        error = math.remainder(self.goal_yaw - theta, math.tau)
        if abs(error) <= s.yaw_tolerance:
            return Command(0.0, 0.0, "arrived", remaining, cross)
        return Command(0.0, self._turn(error), "align", remaining, cross)

    def _turn(self, error: float) -> float:
        s = self.settings
        w = max(min(abs(error) * s.turn_gain, s.max_turn), s.min_turn)
        return math.copysign(w, error)

    def _advance(self, x: float, y: float) -> float:
        """Move the nearest-point index forward (within a window) and return the distance to
        the path there (the cross-track error)."""
        path = self.path
        end = min(len(path), self.nearest + 40)
        window = path[self.nearest:end]
        distances = np.hypot(window[:, 0] - x, window[:, 1] - y)
        best = int(np.argmin(distances))
        self.nearest += best
        if self.loop and self.nearest >= len(path) - 2:
            self.nearest = 0
        return self._segment_distance(x, y)

    def _segment_distance(self, x: float, y: float) -> float:
        path, i = self.path, self.nearest
        best = math.hypot(path[i, 0] - x, path[i, 1] - y)
        for a, b in ((i - 1, i), (i, i + 1)):
            if a < 0 or b >= len(path):
                continue
            ax, ay = path[a]
            ex, ey = path[b, 0] - ax, path[b, 1] - ay
            span = ex * ex + ey * ey
            u = 0.0 if span == 0 else min(max(((x - ax) * ex + (y - ay) * ey) / span, 0.0), 1.0)
            best = min(best, math.hypot(ax + u * ex - x, ay + u * ey - y))
        return best

    def _carrot(self, x: float, y: float, lookahead: float,
                cross: float) -> tuple[float, float]:
        """The first path point at least ``lookahead`` from the robot past the nearest one
        (the last point when none is that far; a loop wraps), pulled back to the farthest one
        the straight line to which passes the path before it within the corridor (plus the
        robot's own distance from the path). Between bends the path is straight, so only its
        bends are checked (none on a straight stretch), the farthest carrot found by halving."""
        path, n = self.path, len(self.path)
        far = self._lookahead_index(x, y, lookahead)
        if self.settings.corridor <= 0.0 or far <= self.nearest + 1:
            return float(path[far % n, 0]), float(path[far % n, 1])
        span = np.arange(self.nearest + 1, far) % n if far >= n else \
            slice(self.nearest + 1, far)
        inner = np.flatnonzero(self.bends[span]) + 1  # bends before the carrot (from nearest)
        if len(inner) == 0:
            return float(path[far % n, 0]), float(path[far % n, 1])
        corners = path[(inner + self.nearest) % n] - (x, y)
        width = self.settings.corridor + cross
        good, bad = int(inner[0]), far - self.nearest  # no bend before the first bend
        if _within(path[far % n] - (x, y), corners, width):
            good = bad
        while bad - good > 1:
            middle = (good + bad) // 2
            before = corners[:int(np.searchsorted(inner, middle))]
            if _within(path[(self.nearest + middle) % n] - (x, y), before, width):
                good = middle
            else:
                bad = middle
        k = (self.nearest + good) % n
        return float(path[k, 0]), float(path[k, 1])

    def _lookahead_index(self, x: float, y: float, lookahead: float) -> int:
        """Index (not wrapped) of the first path point at least ``lookahead`` from the robot
        past the nearest one; the last one when none is that far."""
        path, n = self.path, len(self.path)
        stop = self.nearest + n if self.loop else n
        start = self.nearest
        while start < stop:
            end = min(start + LOOKAHEAD_WINDOW, stop)
            window = path[start:end] if end <= n else path[np.arange(start, end) % n]
            dx, dy = window[:, 0] - x, window[:, 1] - y
            far = np.flatnonzero(dx * dx + dy * dy >= lookahead * lookahead)
            if len(far):
                return start + int(far[0])
            start = end
        return n - 1


def _within(end: np.ndarray, points: np.ndarray, width: float) -> bool:
    """Whether every one of ``points`` lies within ``width`` of the segment from the origin to
    ``end``."""
    span = max(float(end @ end), 1e-12)
    u = np.minimum(np.maximum(points @ end / span, 0.0), 1.0)
    off = points - u[:, None] * end
    return float(np.einsum("ij,ij->i", off, off).max()) <= width * width


def bends(path: np.ndarray, loop: bool = False) -> np.ndarray:
    """Which points of the path it turns at (a loop also at its ends)."""
    out = np.zeros(len(path), dtype=bool)
    if len(path) > 2:
        step = np.diff(path, axis=0)
        cross = step[:-1, 0] * step[1:, 1] - step[:-1, 1] * step[1:, 0]
        dot = np.einsum("ij,ij->i", step[:-1], step[1:])
        out[1:-1] = np.abs(np.arctan2(cross, dot)) > BEND_RAD
    if loop and len(path):
        out[0] = out[-1] = True
    return out


def densify(points: np.ndarray, spacing: float) -> np.ndarray:
    """The polyline with points at most ``spacing`` apart (ends kept)."""
    points = np.asarray(points, dtype=float)
    if len(points) < 2:
        return points
    out = [points[:1]]
    for a, b in itertools.pairwise(points):
        n = max(1, math.ceil(math.hypot(*(b - a)) / spacing))
        f = (np.arange(1, n + 1) / n)[:, None]
        out.append(a + f * (b - a))
    return np.vstack(out)


def figure_eight(size: float, spacing: float = 0.02) -> np.ndarray:
    """A lemniscate of Gerono ``size`` m wide (two lobes of ``size``/2 each) starting at its
    crossing point heading +x, as (N, 2) points in the frame of its start; one full lap."""
    t = np.linspace(0.0, math.tau, max(16, math.ceil(3.2 * size / spacing)))
    a = size / 2.0
    xs, ys = a * np.sin(t), a * np.sin(t) * np.cos(t)
    turn = -math.atan2(1.0, 1.0)  # the curve leaves the crossing at 45 degrees
    c, s = math.cos(turn), math.sin(turn)
    return np.column_stack((c * xs - s * ys, s * xs + c * ys))


def transform(points: np.ndarray, pose: Pose) -> np.ndarray:
    """Points given in the frame of ``pose`` expressed in the frame ``pose`` is given in."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.column_stack((pose[0] + c * points[:, 0] - s * points[:, 1],
                            pose[1] + s * points[:, 0] + c * points[:, 1]))
