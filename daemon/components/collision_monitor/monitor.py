# Collision monitor: stop, slowdown and approach limits on a twist from the latest revolution.
from __future__ import annotations

import math
from bisect import bisect_right
from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from daemon.components.collision_monitor.footprint import Footprint
from daemon.components.collision_monitor.sweep import SCALE, contact_travel, path_direction

Array = npt.NDArray[np.float64]

ACTIONS = ("none", "slowdown", "limit", "stop")  # least to most severe
POSE_HISTORY = 256  # odometry poses kept for placing a revolution (~5 s at 50 Hz)
#: once stopped short of the stop zone, motion toward it resumes only with this much room (m)
STOP_HYSTERESIS = 0.03
#: an approach limit below this speed (travel units per s) stops the robot instead: near the
#: stop zone the limit falls as room / reaction time, and creeping the last centimetres
#: would take seconds
CREEP_SPEED = 0.05


@dataclass(frozen=True)
class MonitorSettings:
    """What the monitor needs to know (``[collision_monitor]`` plus the limits)."""

    footprint: Footprint
    stop_margin: float = 0.10
    slowdown_margin: float = 0.35
    slowdown_ratio: float = 0.5
    time_before_collision: float = 1.0
    reaction_time: float = 0.12  # from deciding to slow down until the wheels do
    motor_lag: float = 0.1  # of that, the wheels' time constant (the rest: the loop may stall)
    min_points: int = 1
    source_timeout: float = 0.5
    stale_action: str = "stop"
    linear_deceleration: float = 4.0
    angular_deceleration: float = 12.0
    max_linear: float = 2.0
    max_angular: float = 2.0
    bins: int = 180
    retransform_distance: float = 0.15
    retransform_angle: float = math.radians(5.0)

    @property
    def horizon(self) -> float:
        """Longest travel the approach check ever projects."""
        return math.hypot(self.max_linear, SCALE * self.max_angular) * \
            self.time_before_collision


@dataclass(frozen=True)
class Verdict:
    """The monitor's answer for one target twist."""

    linear: float
    angular: float
    brake: bool
    action: str
    reason: str


@dataclass(frozen=True)
class Path:
    """A twist's path direction, its speed along it and the table bins around it."""

    psi: float
    sigma: float
    bins: list[int]


@dataclass
class Table:
    """The revolution placed at one odometry pose: points in the robot frame there, the
    nearest clearance, and (filled lazily) the free travel per path direction bin."""

    pose: tuple[float, float, float]
    px: Array
    py: Array
    nearest: float
    zone: str
    bins: dict[int, tuple[float, float]]
    #: no path can bring any disc into the slowdown zone within this much travel
    open_travel: float = 0.0


class WheelLag:
    """The speed the wheels are assumed to have: the commanded path speed through a first-order
    lag of ``time_constant`` s. A motor that lags its command keeps running faster than the
    command while it brakes; a lag at least as slow as the real one overestimates that speed,
    which is the safe side (the run-time check in
    :mod:`daemon.components.collision_monitor.braking` compares it with the encoders)."""

    def __init__(self, time_constant: float) -> None:
        self.time_constant = time_constant
        self.speed = 0.0
        self._command = 0.0
        self._last: float | None = None

    def follow(self, command: float, now: float) -> None:
        """The command in force from ``now`` on (the previous one held until then)."""
        if self._last is not None and now > self._last:
            tau = self.time_constant
            keep = math.exp(-(now - self._last) / tau) if tau > 0 else 0.0
            self.speed = self._command + (self.speed - self._command) * keep
        self._last = max(now, self._last) if self._last is not None else now
        self._command = command
        if self.time_constant <= 0:
            self.speed = command


class CollisionMonitor:
    """Limits a target twist so the robot stays out of obstacles seen by the lidar.

    Per revolution (:meth:`on_scan`) the points are placed in the odometry frame at the pose
    the robot had when the revolution's first ray was taken; the tick reports the odometry
    pose (:meth:`observe`), and when the robot has moved or turned noticeably the points are
    placed around it again. For a twist the path direction picks two neighbouring bins whose
    free travel (footprint grown by the stop margin, and by the slowdown margin) is computed
    once per placement, so a command costs a dictionary lookup and a little arithmetic.
    The distance moved since the placement is taken off the free travel. Takes its time from
    the caller; never reads a clock.
    """

    def __init__(self, settings: MonitorSettings) -> None:
        self.settings = settings
        fp = settings.footprint
        grow = np.array([0.0, 0.0, 1.0])  # discs grown by each zone's margin
        self._layers = np.concatenate([fp.discs + grow * settings.stop_margin,
                                       fp.discs + grow * settings.slowdown_margin])
        self._disc_count = len(fp.discs)
        offsets = float(np.hypot(fp.discs[:, 0], fp.discs[:, 1]).max())
        #: a disc moves at most this many metres per unit of travel (corners swing out)
        self._stretch = stretch = math.hypot(1.0, offsets / SCALE)
        self.reach = settings.horizon * stretch + offsets + float(fp.discs[:, 2].max()) + \
            settings.slowdown_margin
        self._bin_width = 2.0 * math.pi / settings.bins
        self._poses: deque[tuple[float, float, float, float]] = deque(maxlen=POSE_HISTORY)
        self._odom_points: tuple[Array, Array] | None = None
        #: every point of the revolution, the goal's too (odometry frame)
        self._all_points: tuple[Array, Array] | None = None
        #: the goal the robot is meant to touch (a dock's arms, odometry frame), and the band
        #: around it whose points are not obstacles
        self.goal_zone: tuple[Array, float] | None = None
        self.goal_points = 0
        self.table: Table | None = None
        self.scan_first: float | None = None
        self.scan_last: float | None = None
        self.scans = 0
        self.bin_computations = 0
        self._stopped = False
        self._wheels = WheelLag(settings.motor_lag)
        #: the twists of the last check that needed the sweep (None: open space)
        self._in_use: tuple[tuple[float, float], tuple[float, float]] | None = None

    # -- inputs -----------------------------------------------------------------------------

    def observe(self, now: float, x: float, y: float, theta: float) -> None:
        """The odometry pose at ``now`` (once per control tick). While the last check needed
        the sweep, the points are placed around the robot again here, on the tick, when it
        has moved far enough, with the bins of that check ready, so that the commands'
        event path finds them."""
        self._poses.append((now, x, y, theta))
        if self._in_use is not None and self.table is not None:
            placed = self.table
            if self._refresh() is not placed:
                self.warm(*self._in_use)

    def _refresh(self) -> Table:
        """The table, placed around the robot again if it has moved or turned noticeably
        since (done on demand: turning in place with a round footprint needs no table)."""
        table = self.table
        assert table is not None
        x, y, theta = self.pose
        s = self.settings
        if math.hypot(x - table.pose[0], y - table.pose[1]) > s.retransform_distance or \
                abs(_wrap(theta - table.pose[2])) > s.retransform_angle:
            self._place((x, y, theta))
            assert self.table is not None
            table = self.table
        return table

    def on_scan(self, px: Array, py: Array, t_first: float, t_last: float) -> None:
        """A whole revolution: points (robot frame, m) as seen from where the robot was at
        ``t_first``, the time of its first ray; ``t_last`` is the time of its last ray."""
        if self.scan_last is not None and t_last < self.scan_last:
            return  # older than the revolution already in use
        x0, y0, th0 = self._pose_at(t_first)
        keep = np.isfinite(px) & np.isfinite(py)
        keep &= np.hypot(px, py) <= self.reach + 2.0 * self.settings.retransform_distance + 1.0
        px, py = px[keep], py[keep]
        c, s = math.cos(th0), math.sin(th0)
        self._all_points = (x0 + c * px - s * py, y0 + s * px + c * py)
        self._odom_points = self._without_goal(*self._all_points)
        self.scan_first, self.scan_last = t_first, t_last
        self.scans += 1
        self._place(self.pose)

    def set_goal_zone(self, segments: list[tuple[float, float, float, float]] | None,
                      band: float = 0.0) -> None:
        """The goal the robot is meant to touch (segments in the odometry frame; None: no
        goal): points within ``band`` of them are not obstacles until it is cleared. Every
        other point keeps its margins."""
        self.goal_zone = None if not segments else (np.array(segments, dtype=float), band)
        if self._all_points is not None:
            self._odom_points = self._without_goal(*self._all_points)
            self._place(self.pose)

    def _without_goal(self, ox: Array, oy: Array) -> tuple[Array, Array]:
        zone = self.goal_zone
        if zone is None:
            self.goal_points = 0
            return ox, oy
        segments, band = zone
        distance = np.full(len(ox), np.inf)
        for x1, y1, x2, y2 in segments:
            ex, ey = x2 - x1, y2 - y1
            u = np.clip(((ox - x1) * ex + (oy - y1) * ey) / max(ex * ex + ey * ey, 1e-12),
                        0.0, 1.0)
            distance = np.minimum(distance, np.hypot(x1 + u * ex - ox, y1 + u * ey - oy))
        obstacle = distance > band
        self.goal_points = int(len(ox) - obstacle.sum())
        return ox[obstacle], oy[obstacle]

    @property
    def pose(self) -> tuple[float, float, float]:
        if not self._poses:
            return (0.0, 0.0, 0.0)
        _, x, y, theta = self._poses[-1]
        return x, y, theta

    def _pose_at(self, t: float) -> tuple[float, float, float]:
        """The odometry pose at ``t`` (the latest at or before it; the oldest known when
        ``t`` is older than the history)."""
        if not self._poses:
            return (0.0, 0.0, 0.0)
        index = bisect_right(self._poses, t, key=lambda p: p[0])
        _, x, y, theta = self._poses[max(0, index - 1)]
        return x, y, theta

    def _place(self, pose: tuple[float, float, float]) -> None:
        if self._odom_points is None:
            return
        ox, oy = self._odom_points
        cos, sin = math.cos(pose[2]), math.sin(pose[2])
        dx, dy = ox - pose[0], oy - pose[1]
        px, py = cos * dx + sin * dy, -sin * dx + cos * dy
        keep = np.hypot(px, py) <= self.reach
        px, py = px[keep], py[keep]
        s = self.settings
        nearest = self._kth(s.footprint.clearance(px, py))
        zone = "stop" if nearest <= s.stop_margin else (
            "slowdown" if nearest <= s.slowdown_margin else "clear")
        if s.footprint.round:
            to_discs = nearest  # the one disc is the footprint
        else:
            discs = s.footprint.discs
            to_discs = self._kth((np.hypot(px[None, :] - discs[:, 0:1],
                                           py[None, :] - discs[:, 1:2]) -
                                  discs[:, 2:3]).min(axis=0))
        open_travel = (to_discs - s.slowdown_margin) / self._stretch
        self.table = Table(pose, px, py, nearest, zone, {}, open_travel)

    def _kth(self, values: Array) -> float:
        k = self.settings.min_points
        if len(values) < k:
            return math.inf
        return float(np.partition(values, k - 1)[k - 1]) if k > 1 else float(values.min())

    # -- the check ---------------------------------------------------------------------------

    def scan_age(self, now: float) -> float | None:
        """Seconds since the last ray of the latest revolution (None before the first)."""
        return None if self.scan_last is None else now - self.scan_last

    def stale(self, now: float) -> bool:
        age = self.scan_age(now)
        return age is None or age > self.settings.source_timeout or self.table is None

    def limit(self, linear: float, angular: float, current_linear: float,
              current_angular: float, now: float) -> Verdict:
        """The safe version of the target twist, given the current (commanded) velocity."""
        self._wheels.follow(path_direction(current_linear, current_angular)[1], now)
        if self.stale(now):
            return self._stale(linear, angular, current_linear, current_angular, now)
        target = self._path(linear, angular)
        current = target if (current_linear, current_angular) == (linear, angular) else \
            self._path(current_linear, current_angular)
        if target is None and current is None:
            return Verdict(linear, angular, False, "none", "")
        table = self._refresh()
        travel = self._travel(table, current_linear, current_angular, now)
        measured = self._wheels.speed
        fastest = max(target.sigma if target else 0.0, current.sigma if current else 0.0,
                      measured)
        if (table.open_travel - travel) > fastest * self.settings.time_before_collision:
            self._stopped = False  # nothing any path could reach in time: no sweep needed
            self._in_use = None
            return Verdict(linear, angular, False, "none", "")
        self._in_use = ((linear, angular), (current_linear, current_angular))
        self._compute(table, (target.bins if target else []) +
                      (current.bins if current and current is not target else []))
        fraction, action, reason, hard = self._judge(table, target, travel, self._stopped,
                                                     measured)
        # the motion as it is now may need the emergency deceleration whatever the target
        unsafe_now = hard if current is target else \
            self._judge(table, current, travel, measured=measured)[3]
        self._stopped = action == "stop"
        if action in ("none", "slowdown") and unsafe_now:
            action, reason = "limit", "braking: the current motion runs into an obstacle"
        brake = hard or unsafe_now
        return Verdict(linear * fraction, angular * fraction, brake, action, reason)

    def _stale(self, linear: float, angular: float, current_linear: float,
               current_angular: float, now: float) -> Verdict:
        age = self.scan_age(now)
        why = "no lidar revolution yet" if age is None else f"lidar scan {age:.2f} s old"
        if self.settings.stale_action == "stop" or self.table is None:
            return Verdict(0.0, 0.0, True, "stop", f"{why}: stopped")
        table = self._refresh()
        target = self._path(linear, angular)
        if target is not None:
            self._compute(table, target.bins)
        travel = self._travel(table, current_linear, current_angular, now)
        fraction, action, _, _ = self._judge(table, target, travel)
        if action == "stop":
            return Verdict(0.0, 0.0, True, "stop", f"{why}: stopped by the last scan")
        fraction = min(fraction, self.settings.slowdown_ratio)
        return Verdict(linear * fraction, angular * fraction, True, "slowdown",
                       f"{why}: slowed down")

    def _path(self, linear: float, angular: float) -> Path | None:
        """The path a twist follows, or None when it sweeps nothing (standing still, or
        turning in place with a round footprint)."""
        psi, sigma = path_direction(linear, angular)
        if sigma == 0.0 or (linear == 0.0 and self.settings.footprint.round):
            return None
        position = (psi % (2.0 * math.pi)) / self._bin_width
        low = math.floor(position)
        count = self.settings.bins
        bins = [low % count] if position - low <= 1e-9 else [low % count, (low + 1) % count]
        return Path(psi, sigma, bins)

    def _travel(self, table: Table, current_linear: float, current_angular: float,
                now: float) -> float:
        """How far the robot may have moved since the points were placed (travel units)."""
        t_pose, x, y, theta = self._poses[-1] if self._poses else (now, 0.0, 0.0, 0.0)
        moved = math.hypot(x - table.pose[0], y - table.pose[1])
        if not self.settings.footprint.round:  # its corners swing out when it turns
            moved += self.settings.footprint.reach * abs(_wrap(theta - table.pose[2]))
        if now > t_pose:
            moved += math.hypot(current_linear, SCALE * current_angular) * (now - t_pose)
        return moved

    def _judge(self, table: Table, path: Path | None, travel: float, stopped: bool = False,
               measured: float = 0.0) -> tuple[float, str, str, bool]:
        """The fraction of a path's speed that is safe, the action, why, and whether keeping
        the speed would need more than the emergency deceleration can give (``stopped``: the
        last target was stopped; it needs a little more room to move on; ``measured``: the
        speed the wheels are assumed to have, which a slow motor keeps above the command while
        braking)."""
        if path is None:
            return 1.0, "none", "", False
        s = self.settings
        stop_free, slow_free = table.bins[path.bins[0]]
        if len(path.bins) > 1:
            other = table.bins[path.bins[1]]
            stop_free, slow_free = min(stop_free, other[0]), min(slow_free, other[1])
        room = stop_free - travel
        hysteresis = STOP_HYSTERESIS if stopped else 0.0
        if room <= hysteresis:
            return 0.0, "stop", "obstacle in the stop zone in the way", True
        deceleration = self._deceleration(path.psi)
        if room <= hysteresis + _braking_room(CREEP_SPEED, deceleration, s.reaction_time):
            # the approach limit would creep the last centimetres for seconds: stop here
            return 0.0, "stop", f"approach: stopped {room:.2f} m short of the stop zone", True
        sigma = path.sigma
        allowed, action, reason, hard = sigma, "none", "", False
        if room <= max(sigma, measured) * s.time_before_collision:
            cap = _braking_speed(room, deceleration, s.reaction_time, measured, s.motor_lag)
            if cap < sigma:
                allowed, action, hard = cap, "limit", True
                reason = f"approach: {room:.2f} m to the stop zone"
        if slow_free - travel <= 0.0 and sigma * s.slowdown_ratio < allowed:
            allowed, action = sigma * s.slowdown_ratio, "slowdown"
            reason = "obstacle in the slowdown zone"
        return allowed / sigma, action, reason, hard

    def _compute(self, table: Table, bins: list[int]) -> None:
        """Fill the table's bin cache for ``bins`` (the missing ones computed together)."""
        missing = [b for b in dict.fromkeys(bins) if b not in table.bins]
        if not missing:
            return
        self.bin_computations += len(missing)
        if len(table.px) == 0:
            table.bins.update(dict.fromkeys(missing, (math.inf, math.inf)))
            return
        travel = contact_travel([b * self._bin_width for b in missing], table.px, table.py,
                                self._layers, self.settings.horizon)
        per_layer = travel.reshape(len(missing), 2, self._disc_count, -1).min(axis=2)
        for b, layers in zip(missing, per_layer, strict=True):
            table.bins[b] = (self._kth(layers[0]), self._kth(layers[1]))

    def warm(self, *twists: tuple[float, float]) -> None:
        """Compute the bins these twists will need now, so the next commands find them."""
        if self.table is None:
            return
        paths = [p for p in (self._path(v, w) for v, w in twists) if p is not None]
        if not paths:
            return
        table = self._refresh()
        if table.open_travel > max(p.sigma for p in paths) * self.settings.time_before_collision:
            return  # open space: the check will not need them
        self._compute(table, [b for path in paths for b in path.bins])

    def _deceleration(self, psi: float) -> float:
        """The emergency deceleration along a path direction, in travel units per s²."""
        s = self.settings
        c, b = abs(math.cos(psi)), abs(math.sin(psi))
        linear = s.linear_deceleration / c if c > 1e-12 else math.inf
        angular = s.angular_deceleration * SCALE / b if b > 1e-12 else math.inf
        return min(linear, angular)

    # -- reporting ---------------------------------------------------------------------------

    def nearest(self) -> float | None:
        return None if self.table is None or not math.isfinite(self.table.nearest) else \
            self.table.nearest

    def zone(self, now: float) -> str:
        if self.stale(now):
            return "unknown"
        assert self.table is not None
        return self.table.zone


def _braking_room(speed: float, deceleration: float, reaction: float) -> float:
    """The room the robot needs to stop from ``speed``: it reacts, then brakes."""
    return speed * reaction + speed * speed / (2.0 * deceleration)


def _braking_speed(room: float, deceleration: float, reaction: float,
                   measured: float = 0.0, lag: float = 0.0) -> float:
    """Fastest commanded speed ``v`` from which the robot stops within ``room``: the command
    holds for ``reaction - lag`` s, then ramps down at ``deceleration``, and the wheels follow
    it ``lag`` s behind, which costs ``lag`` times their speed: the faster of ``v`` and the
    ``measured`` speed (a motor that lags its command is still faster while it brakes).
    v*(reaction - lag) + v²/(2a) + lag*max(v, measured) = room."""
    a = deceleration
    v = a * (-reaction + math.sqrt(reaction * reaction + 2.0 * room / a))
    if v >= measured:
        return v
    hold = reaction - lag
    rest = max(0.0, room - lag * measured)
    return a * (-hold + math.sqrt(hold * hold + 2.0 * rest / a))


def _wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))

