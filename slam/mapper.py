# The mapper: scan-to-submap matching, key scans in a pose graph with loop closure, a rendered grid.
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from slam.farloops import FarLoopConfig, far_loops, residual
from slam.field import DistanceField
from slam.globalloc import FOUND, NOT_FOUND, GlobalConfig, GlobalLocalizer
from slam.graph import PoseGraph
from slam.grid import OccupancyGrid
from slam.matcher import Match, SearchWindow, match, polish
from slam.pose import Pose2, between, compose, inverse, transform_points
from slam.smooth import learn_noise, smooth
from slam.submaps import SubmapAtlas

IDENTITY: Pose2 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class MapperConfig:
    """Tunables of the mapper (lengths in m, angles in rad).

    resolution: cell size of the occupancy grid.
    match_resolution: cell size of the distance fields scans are matched against (map mode).
    max_range: returns farther than this are dropped (neither free space nor obstacle).
    mode: "map" builds a map; "localize" tracks the pose in the fixed grid given to Mapper.
    loop_closure: look for and close loops (map mode).
    max_cells: bound on the grid's area (see OccupancyGrid).
    key_distance, key_angle: a scan becomes a key scan (graph node, integrated into the grid)
        once the pose moved this far or turned this much since the last key scan.
    submap_keys: how many recent key scans form the submap each scan is matched against.
    submap_every: the submap's distance field is rebuilt every this many key scans (and after
        every graph optimisation); in between, scans match the slightly older submap.
    track_window: the correlative search around the odometry prediction (± m, ± rad).
    min_score: a match scoring below this (0..1) is refused and odometry is used instead.
    score_sigma: width (m) of the likelihood that turns point distances into the score.
    field_max_distance: distance fields are truncated here (m); the refinement's reach.
    loop_min_travel: a loop candidate lies at least this far back along the path (m).
    loop_search_radius: ... and within this distance of the current pose estimate (m).
    loop_window: correlative search half-widths (m, rad) for a loop closure.
    loop_submap_keys: key scans on each side of the candidate that form its submap.
    loop_min_score: strict acceptance score of a loop closure.
    loop_drift: (m, share of the path) a loop closure may move the pose by at most the first
        plus the second times the path driven since the last accepted closure (in translation;
        and at most ``loop_drift_angle`` (rad, rad per m) in rotation): a pose a closure
        anchored a moment ago cannot have drifted a metre since (an alias of the place, as
        shelf rows are, is refused). inf: no bound.
    loop_every: try a loop closure at most every this many key scans.
    optimize_every: optimise the graph automatically once this many key scans passed since the
        first unapplied loop closure (0: never; the caller runs Mapper.optimize()).
    odometry_sigmas, match_sigmas, loop_sigmas: standard deviations (x, y, theta) of graph
        edges from odometry alone, from scan matching, and from a loop closure.
    relocalize_window: localize mode, the wide search after set_pose or when lost (± m, ± rad).
    lost_after: localize mode, consecutive refused matches before tracking is declared lost.
    max_trajectory: per-scan trajectory entries kept (oldest dropped first).
    stall_gap, stall_follow: after scans whose odometry pose repeated the one before (a
        stalled odometry stream, which then reports the stalled motion in a jump, sometimes
        spread over two scans), each of the next ``stall_follow`` scans is also matched
        around the pose of the last scan with fresh odometry before the stall composed with
        the odometry's motion since then, when that prediction differs from the usual one by
        more than ``stall_gap`` (m, rad); the better score wins. (The usual prediction adds
        the jump on top of the motion the matcher already followed during the stall.)
    keys_per_submap: map mode, the map is rendered from rigid submaps of this many
        consecutive key scans, composed by pose (``slam.submaps``).
    global_search: localize mode, once lost (``lost_after``) search the whole map for the
        pose (``slam.globalloc``, tuned by ``global_config``), as after ``find_pose()``.
        If the scan fits several places alike, each is followed by odometry and matched
        again on every scan; the sum of its log scores must lead the next one's by
        ``global_lead`` before it is taken. While tracking, a match scoring below
        ``suspect_share`` x the median of the last good ones counts as refused (the robot
        was carried or slipped): ``lost_after`` of them in a row start the global search.
        Every ``global_check_every`` tracked scans (0: never) the whole map is searched
        too: if its best place is elsewhere (a carry to a place that looks alike nearby),
        its best three and the tracked pose are followed until one leads.
    """

    resolution: float = 0.05
    match_resolution: float = 0.05
    max_range: float = 12.0
    mode: str = "map"
    loop_closure: bool = True
    max_cells: int = 4_000_000
    key_distance: float = 0.3
    key_angle: float = math.radians(12)
    submap_keys: int = 30
    submap_every: int = 3
    track_window: tuple[float, float] = (0.2, math.radians(6))
    min_score: float = 0.3
    score_sigma: float = 0.05
    field_max_distance: float = 0.5
    loop_min_travel: float = 10.0
    loop_search_radius: float = 4.0
    loop_window: tuple[float, float] = (2.5, math.radians(25))
    loop_submap_keys: int = 12
    loop_min_score: float = 0.55
    loop_drift: tuple[float, float] = (0.3, 0.1)
    loop_drift_angle: tuple[float, float] = (math.radians(5), math.radians(2))
    loop_every: int = 2
    optimize_every: int = 5
    odometry_sigmas: tuple[float, float, float] = (0.2, 0.2, math.radians(5))
    match_sigmas: tuple[float, float, float] = (0.03, 0.03, math.radians(0.5))
    loop_sigmas: tuple[float, float, float] = (0.05, 0.05, math.radians(1))
    relocalize_window: tuple[float, float] = (1.0, math.radians(30))
    lost_after: int = 5
    max_trajectory: int = 1_000_000
    search_penalty: float = 0.05
    prior_weights: tuple[float, float] = (0.0, 0.0)
    refine_tolerance: float = 0.0
    prior_scale: float = 0.0
    prior_points: float = 20.0
    prior_window: int = 200
    loop_trust: tuple[float, float] = (math.inf, math.inf)
    loop_confirm: tuple[float, float] = (0.15, math.radians(1.5))
    loop_confirm_keys: int = 10
    loop_outlier: tuple[float, float] = (math.inf, math.inf)
    loop_bounded: bool = True
    weak_score: float = 0.0
    weak_gate: float = 3.0
    stall_gap: tuple[float, float] = (0.1, math.radians(3))
    stall_follow: int = 3
    keys_per_submap: int = 20
    global_search: bool = True
    global_lead: float = 0.7
    suspect_share: float = 0.6
    global_check_every: int = 100
    global_config: GlobalConfig = field(default_factory=GlobalConfig)


@dataclass(frozen=True)
class ScanResult:
    """What the mapper made of one scan (see the module's API notes)."""

    pose: Pose2
    map_to_odom: Pose2
    matched: bool
    score: float
    covariance: tuple[float, ...]
    lost: bool
    #: localize mode: tracking, lost, searching (the global search found nothing sure yet)
    #: or ambiguous (it found several places alike: ``candidates``); map mode: tracking
    status: str = "tracking"
    candidates: tuple[tuple[Pose2, float], ...] = ()


@dataclass
class KeyScan:
    """A graph node's scan: points in the base frame, the odometry pose and the stamp."""

    points: np.ndarray
    odom: Pose2
    stamp: float
    travelled: float  # path length (m) from the first key scan


@dataclass
class Counters:
    scans: int = 0
    matched: int = 0
    loop_attempts: int = 0
    loop_closures: int = 0
    optimizations: int = 0
    last_score: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)


def windows(linear: float, angular: float, resolution: float) -> tuple[SearchWindow, ...]:
    """Coarse-to-fine correlative searches covering ± linear m and ± angular rad."""
    coarse_step = max(resolution, min(0.1, linear / 4))
    coarse_turn = max(math.radians(0.5), min(math.radians(2), angular / 6))
    steps = [SearchWindow(linear, angular, coarse_step, coarse_turn, max(0.1, coarse_step))]
    if coarse_step > resolution or coarse_turn > math.radians(0.5):
        steps.append(SearchWindow(coarse_step, coarse_turn, resolution, math.radians(0.5),
                                  max(0.05, resolution)))
    return tuple(steps)


class Mapper:
    """Online 2D SLAM (map mode) or localisation in a fixed grid (localize mode).

    Not thread-safe: one caller at a time (add_scan, set_pose, optimize, grid). In map mode
    the grid is composed from submaps (``slam.submaps``) on access: only the submaps that a
    graph optimisation moved are re-placed, so its cost does not grow with the run."""

    def __init__(self, config: MapperConfig, grid: OccupancyGrid | None = None,
                 initial_pose: Pose2 = IDENTITY) -> None:
        if config.mode not in ("map", "localize"):
            raise ValueError(f"mode must be 'map' or 'localize', got {config.mode!r}")
        if config.mode == "localize" and grid is None:
            raise ValueError("localize mode needs a grid (a loaded map)")
        self.config = config
        self._grid = grid if grid is not None else OccupancyGrid(config.resolution,
                                                                config.max_cells)
        #: the graph moved since the submaps were last composed
        self._grid_stale = False
        self._atlas = SubmapAtlas(config.resolution, config.max_cells, config.keys_per_submap)
        self._pose = initial_pose
        self._last_odom: Pose2 | None = None
        self._graph = PoseGraph()
        self._keys: list[KeyScan] = []
        self._rel_to_key = IDENTITY
        self._submap: DistanceField | None = None
        self._pending_loops = 0
        self._last_loop_key = -10**9
        self._first_pending_key = 0
        self._submap_age = 0
        self._trajectory: list[tuple[float, int, Pose2]] = []
        self._counts = Counters()
        self._lost = False
        self._corrections: list[tuple[float, float]] = []
        self._held_loop: tuple[int, int, Pose2, Pose2] | None = None
        #: the path length (m) at the key scan of the last accepted loop closure
        self._anchored_at = 0.0
        self._refused_in_a_row = 0
        #: (key, pose relative to it, odometry pose) of the last scan with fresh odometry
        #: before the last stall of the odometry stream
        self._odom_anchor: tuple[int, Pose2, Pose2] | None = None
        #: scans with fresh odometry since the last one whose odometry repeated its predecessor's
        self._after_stall = 10**9
        self._wide_search = config.mode == "localize"
        self._fixed = (DistanceField.from_grid(self._grid, config.field_max_distance)
                       if config.mode == "localize" else None)
        self._global: GlobalLocalizer | None = None
        #: localize mode: the next scans search the whole map (find_pose, or lost)
        self._searching = False
        self.global_searches = 0
        #: while ambiguous: [pose, sum of log scores] per place the scan fitted, followed
        #: by odometry and re-matched each scan until one is clearly ahead
        self._hypotheses: list[tuple[Pose2, float]] = []
        #: localize mode: scores of the last accepted matches, and how often a run of poor
        #: ones (``suspect_share``) sent the mapper to search the whole map again
        self._recent_scores: list[float] = []
        self.kidnaps = 0
        self._since_check = 0

    # ------------------------------------------------------------------ public API

    @property
    def grid(self) -> OccupancyGrid:
        """The current map: the fixed one (localize mode), else the submaps composed at their
        current graph poses."""
        if self.config.mode == "map" and self._keys:
            self._atlas.compose(self._graph.poses, self._key_points, moved=self._grid_stale)
            self._grid_stale = False
            self._grid = self._atlas.grid()
        return self._grid

    def _key_points(self, key: int) -> np.ndarray:
        return self._keys[key].points

    @property
    def trajectory(self) -> list[tuple[float, Pose2]]:
        """(stamp, corrected pose) per scan, with the latest graph poses."""
        out = []
        for stamp, key, rel in self._trajectory:
            out.append((stamp, compose(self._graph.pose(key), rel) if key >= 0 else rel))
        return out

    def set_pose(self, pose: Pose2, odom_pose: Pose2 | None = None) -> None:
        """(Re)initialise the pose; the next scans search widely around it (localize mode)."""
        self._pose = pose
        if odom_pose is not None:
            self._last_odom = odom_pose
        self._wide_search = True
        self._searching = False
        self._hypotheses = []
        self._refused_in_a_row = 0

    def find_pose(self) -> None:
        """Localize mode: forget the pose; the next scans search the whole map for it."""
        if self.config.mode != "localize":
            raise ValueError("find_pose needs localize mode (a loaded map)")
        self._searching = True
        self._lost = True
        self._hypotheses = []

    def add_scan(self, odom_pose: Pose2, points_xy: np.ndarray, stamp: float) -> ScanResult:
        """One revolution: odometry pose of the base, points (N, 2) in the base frame."""
        points = self._usable(points_xy)
        predicted = self._predict(odom_pose)
        stale = self._last_odom is not None and tuple(odom_pose) == tuple(self._last_odom)
        self._last_odom = odom_pose
        self._counts.scans += 1
        if self.config.mode == "localize":
            result = self._localize(predicted, points)
            self._record(stamp, -1, result.pose)
        else:
            resumed = (self._resumed_prediction(odom_pose, predicted)
                       if not stale and self._after_stall < self.config.stall_follow else None)
            result = self._map(predicted, points, odom_pose, stamp, resumed)
            self._after_stall = 0 if stale else self._after_stall + 1
            if self._after_stall > self.config.stall_follow:
                _, key, rel = self._trajectory[-1]
                self._odom_anchor = (key, rel, odom_pose)
        self._pose = result.pose
        return result

    def optimize(self) -> None:
        """Optimise the pose graph now (sparse Gauss-Newton, node 0 fixed) and re-place the
        current pose; the grid is re-rendered on next access. Cost grows with the graph:
        tens of ms for thousands of key scans on a 2-core x86."""
        if self._graph.node_count < 2:
            return
        self._graph.optimize()
        limit = self.config.loop_outlier
        if math.isfinite(limit[0]) and self._graph.drop_robust_outliers(*limit):
            self._counts.extra["dropped_loops"] = self._counts.extra.get(
                "dropped_loops", 0) + 1
            self._graph.optimize()
        self._pending_loops = 0
        self._counts.optimizations += 1
        self._pose = compose(self._graph.pose(len(self._keys) - 1), self._rel_to_key)
        self._submap = None
        self._grid_stale = True

    def close_far_loops(self, cfg: FarLoopConfig | None = None) -> dict[str, int]:
        """Offline, once the log is mapped: loop closures between key scans far apart in
        time (``slam.farloops``: candidates by odometry, a wide match, kept only where
        neighbouring closures agree), added to the graph, which is then optimised. If the
        optimised poses disagree with a kept closure by more than the agreement bound, the
        closures are taken out again and the graph left as it was. Returns the counts."""
        cfg = cfg or FarLoopConfig()
        if len(self._keys) < 2:
            return {"far_candidates": 0, "far_strong": 0, "far_agreeing": 0, "far_accepted": 0}
        keys = self._keys
        kept, counts = far_loops(self._graph.poses, [k.points for k in keys],
                                 np.asarray([k.odom for k in keys], dtype=np.float64),
                                 np.asarray([k.stamp for k in keys]), cfg,
                                 self.config.score_sigma)
        if kept:
            saved = (self._graph.poses.copy(), self._graph.edge_count)
            for i, j, relative, _ in kept:
                self._graph.add_edge(i, j, relative, self.config.loop_sigmas)
            self._graph.optimize(iterations=50)
            if any(d > cfg.agree[0] or a > cfg.agree[1] for d, a in
                   (residual(self._graph.poses, c) for c in kept)):
                self._graph.poses = saved[0]
                self._graph.truncate(saved[1])
                counts["far_reverted"] = len(kept)
            else:
                self._grid_stale = True
                self._submap = None
                self._pose = compose(self._graph.pose(len(keys) - 1), self._rel_to_key)
        self._counts.extra.update(counts)
        return counts

    def refined_trajectory(self, points: list[np.ndarray], window: int = 10, share: int = 4,
                           radius: float = 12.0, resolution: float = 0.075,
                           robust_distance: float = 0.05,
                           odometry: Sequence[Pose2] | None = None) -> list[tuple[float, Pose2]]:
        """The trajectory after an offline pass (``points``: every scan's points, in the order
        they were added): each scan's pose polished (``polish``: converged Levenberg-Marquardt)
        against the distance field of the optimised key scans within ``window`` keys of its
        own, on both sides, and within ``radius`` m of the field's centre key, at
        ``resolution`` (coarser than the online fields' 0.05 m: smoother, and closer on the
        Freiburg logs), Huber past ``robust_distance``; one field serves the scans of
        ``share`` consecutive key scans. With ``odometry`` (every scan's odometry pose), the
        polished poses are then fused with the odometry's motion between consecutive scans
        (``slam.smooth``), each weighted by the noise learnt from how the two disagree over 1
        and 4 scans. The graph and the map are left as they are.
        (Online, a scan is matched against the key scans before it only, and its refinement
        stops at the member of a Gauss-Newton two-cycle its iterations land on.)"""
        poses = self.trajectory
        if len(points) != len(poses) or not self._keys:
            raise ValueError("one points array per scan added is needed")
        out = list(poses)
        groups: dict[int, list[int]] = {}
        for i, (_, key, _) in enumerate(self._trajectory):
            groups.setdefault(max(key, 0) // share, []).append(i)
        for group, members in groups.items():
            centre = min(group * share + share // 2, len(self._keys) - 1)
            field = self._field_of(range(max(0, centre - window),
                                         min(len(self._keys), centre + window + 1)),
                                   self._graph.pose(centre), radius, resolution)
            for i in members:
                scan = self._usable(points[i])
                if len(scan) >= 10:
                    out[i] = (out[i][0], polish(field, scan, out[i][1],
                                                robust_distance=robust_distance))
        if odometry is None:
            return out
        if len(odometry) != len(out):
            raise ValueError("one odometry pose per scan added is needed")
        polished = [pose for _, pose in out]
        pose_sigma, step_sigma = learn_noise(polished, odometry)
        fused = smooth(polished, odometry, pose_sigma, step_sigma)
        return [(stamp, pose) for (stamp, _), pose in zip(out, fused, strict=True)]

    def health(self) -> dict[str, Any]:
        c = self._counts
        return {
            "mode": self.config.mode,
            "scans": c.scans,
            "matched_ratio": c.matched / c.scans if c.scans else 0.0,
            "key_scans": len(self._keys),
            "loop_attempts": c.loop_attempts,
            "loop_closures": c.loop_closures,
            "optimizations": c.optimizations,
            "pending_loop_closures": self._pending_loops,
            "last_score": c.last_score,
            "lost": self._lost,
            "grid_width": self._grid.width,
            "grid_height": self._grid.height,
            "grid_cells": self._grid.width * self._grid.height,
            "grid_bytes": self._grid.nbytes,
            "dropped_points": self._grid.dropped_points,
            "submaps": len(self._atlas.submaps),
            "submaps_bytes": self._atlas.nbytes,
            "submaps_last_placed": self._atlas.last_placed,
        }

    # ------------------------------------------------------------------ shared steps

    def _usable(self, points_xy: np.ndarray) -> np.ndarray:
        points = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
        keep = np.isfinite(points).all(axis=1)
        keep &= np.hypot(points[:, 0], points[:, 1]) <= self.config.max_range
        return points[keep]

    def _predict(self, odom_pose: Pose2) -> Pose2:
        if self._last_odom is None:
            return self._pose
        return compose(self._pose, between(self._last_odom, odom_pose))

    def _resumed_prediction(self, odom_pose: Pose2, predicted: Pose2) -> Pose2 | None:
        """Soon after a stalled odometry stream, the pose of the last scan with fresh odometry
        before it composed with the odometry's motion since then, if it differs from
        ``predicted`` by more than ``stall_gap`` (else None)."""
        if self._odom_anchor is None:
            return None
        key, rel, odom = self._odom_anchor
        anchored = compose(compose(self._graph.pose(key), rel), between(odom, odom_pose))
        gap = between(predicted, anchored)
        limit = self.config.stall_gap
        if math.hypot(gap[0], gap[1]) <= limit[0] and abs(gap[2]) <= limit[1]:
            return None
        return anchored

    def _record(self, stamp: float, key: int, rel: Pose2) -> None:
        self._trajectory.append((stamp, key, rel))
        if len(self._trajectory) > self.config.max_trajectory:
            del self._trajectory[: len(self._trajectory) // 10]

    def _result(self, pose: Pose2, odom_pose: Pose2, found: Match | None) -> ScanResult:
        matched = found is not None
        self._counts.matched += matched
        score = found.score if found is not None else 0.0
        self._counts.last_score = score
        return ScanResult(pose, compose(pose, inverse(odom_pose)), matched, score,
                          self._covariance(found), self._lost)

    def _covariance(self, found: Match | None) -> tuple[float, ...]:
        if found is None:
            sx, sy, st = self.config.odometry_sigmas
            return tuple(np.diag([sx * sx, sy * sy, st * st]).reshape(-1).tolist())
        sx, sy, st = self.config.match_sigmas
        floor = np.diag([sx * sx, sy * sy, st * st])
        try:
            cov = np.linalg.inv(found.information) * self.config.score_sigma ** 2
        except np.linalg.LinAlgError:
            cov = floor * 100
        if not np.all(np.isfinite(cov)):
            cov = floor * 100
        cov = np.clip(cov, -1.0, 1.0) + floor
        return tuple(cov.reshape(-1).tolist())

    # ------------------------------------------------------------------ localize mode

    def _localize(self, predicted: Pose2, points: np.ndarray) -> ScanResult:
        assert self._fixed is not None
        cfg = self.config
        if self._searching:
            return self._search_globally(predicted, points, between(self._pose, predicted))
        if self._wide_search:
            lin, ang = cfg.relocalize_window
        else:
            lin, ang = cfg.track_window
        found = match(self._fixed, points, predicted, windows(lin, ang, cfg.resolution),
                      cfg.score_sigma) if len(points) >= 10 else None
        threshold = cfg.min_score * (1.5 if self._wide_search else 1.0)
        if found is not None and found.score >= threshold and self._suspect(found.score):
            # it fits somewhere near, but far worse than the scans here did: moved (carried,
            # slipped)? Followed, and counted towards lost
            self._refused_in_a_row += 1
            if self._refused_in_a_row >= cfg.lost_after:
                self._refused_in_a_row = 0
                self._recent_scores.clear()
                self._lost = self._wide_search = True
                self._searching = cfg.global_search
                self.kidnaps += 1
                result = self._result(predicted, self._last_odom or IDENTITY, None)
                return ScanResult(result.pose, result.map_to_odom, False, found.score,
                                  result.covariance, True, "lost")
            return self._result(found.pose, self._last_odom or IDENTITY, found)
        if found is not None and found.score >= threshold and self._check_due():
            elsewhere = self._elsewhere(points, found)
            if elsewhere is not None:
                return elsewhere
        if found is not None and found.score >= threshold:
            self._recent_scores.append(found.score)
            if len(self._recent_scores) > 30:
                del self._recent_scores[0]
            self._refused_in_a_row = 0
            self._lost = False
            self._wide_search = False
            return self._result(found.pose, self._last_odom or IDENTITY, found)
        self._refused_in_a_row += 1
        if self._refused_in_a_row >= cfg.lost_after:
            self._lost = True
            self._wide_search = True
            self._searching = cfg.global_search
        result = self._result(predicted, self._last_odom or IDENTITY, None)
        return ScanResult(result.pose, result.map_to_odom, False,
                          found.score if found is not None else 0.0, result.covariance,
                          self._lost, "lost" if self._lost else "tracking")

    def _check_due(self) -> bool:
        every = self.config.global_check_every
        self._since_check += 1
        if not self.config.global_search or every <= 0 or self._since_check < every:
            return False
        self._since_check = 0
        return True

    def _elsewhere(self, points: np.ndarray, tracked: Match) -> ScanResult | None:
        """The periodic whole-map check: a sure pose far from the tracked one starts
        following both (None: it agrees, or it is not sure)."""
        if self._global is None:
            assert self._fixed is not None
            self._global = GlobalLocalizer(self._grid, self._fixed, self.config.global_config)
        self.global_searches += 1
        found = self._global.search(points)
        best = found.candidates[0][0] if found.candidates else tracked.pose
        if found.status == NOT_FOUND or \
                math.hypot(best[0] - tracked.pose[0], best[1] - tracked.pose[1]) < 0.5:
            return None  # the tracked pose is the best place (or nothing fits)
        self.kidnaps += 1
        self._searching = self._lost = True
        candidates = (*found.candidates[:3], (tracked.pose, tracked.score))
        self._hypotheses = [(pose, math.log(max(score, 1e-3))) for pose, score in candidates]
        return self._unsure(tracked.pose, "ambiguous", found.score, candidates)

    def _suspect(self, score: float) -> bool:
        recent = self._recent_scores
        return (not self._wide_search and len(recent) >= 3
                and score < self.config.suspect_share * float(np.median(recent)))

    def _search_globally(self, predicted: Pose2, points: np.ndarray,
                         motion: Pose2) -> ScanResult:
        """The whole map searched for this scan (or, while ambiguous, the places it fitted
        followed by ``motion``, the odometry's since the last scan); a sure pose ends it."""
        if self._hypotheses:
            tracked = self._follow_hypotheses(points, motion)
            if tracked is not None:
                return tracked
        if self._global is None:
            assert self._fixed is not None
            self._global = GlobalLocalizer(self._grid, self._fixed, self.config.global_config)
        self.global_searches += 1
        found = self._global.search(points)
        if found.status == FOUND and found.pose is not None:
            return self._localised(found.pose, found.score, found.candidates)
        if found.status != NOT_FOUND:
            self._hypotheses = [(pose, math.log(max(score, 1e-3)))
                                for pose, score in found.candidates]
        status = "searching" if found.status == NOT_FOUND else found.status
        return self._unsure(predicted, status, found.score, found.candidates)

    def _localised(self, pose: Pose2, score: float,
                   candidates: tuple[tuple[Pose2, float], ...]) -> ScanResult:
        self._searching = self._lost = self._wide_search = False
        self._refused_in_a_row = 0
        self._hypotheses = []
        result = self._result(pose, self._last_odom or IDENTITY, None)
        return ScanResult(pose, result.map_to_odom, True, score, result.covariance, False,
                          "tracking", candidates)

    def _unsure(self, predicted: Pose2, status: str, score: float,
                candidates: tuple[tuple[Pose2, float], ...]) -> ScanResult:
        result = self._result(predicted, self._last_odom or IDENTITY, None)
        return ScanResult(result.pose, result.map_to_odom, False, score, result.covariance,
                          True, status, candidates)

    def _follow_hypotheses(self, points: np.ndarray, motion: Pose2) -> ScanResult | None:
        """Each ambiguous place moved by ``motion`` and matched again; the sums of log scores
        decide once one leads by ``global_lead`` (None: every place failed, search again)."""
        assert self._fixed is not None
        cfg = self.config
        lin, ang = cfg.track_window
        kept: list[tuple[Pose2, float, float]] = []
        for pose, weight in self._hypotheses:
            found = match(self._fixed, points, compose(pose, motion),
                          windows(lin, ang, cfg.resolution), cfg.score_sigma)
            if found.score >= cfg.min_score:
                kept.append((found.pose, weight + math.log(found.score), found.score))
        kept.sort(key=lambda h: -h[1])
        kept = [h for h in kept if h[1] >= kept[0][1] - 2 * cfg.global_lead]
        if not kept:
            self._hypotheses = []
            return None
        self._hypotheses = [(pose, weight) for pose, weight, _ in kept]
        best = kept[0]
        candidates = tuple((pose, score) for pose, _, score in kept[:5])
        if len(kept) == 1 or kept[1][1] <= best[1] - cfg.global_lead:
            return self._localised(best[0], best[2], candidates)
        return self._unsure(best[0], "ambiguous", best[2], candidates)

    # ------------------------------------------------------------------ map mode

    def _map(self, predicted: Pose2, points: np.ndarray, odom_pose: Pose2,
             stamp: float, resumed: Pose2 | None = None) -> ScanResult:
        if not self._keys:
            self._add_key(self._pose, points, odom_pose, stamp, None)
            self._record(stamp, 0, IDENTITY)
            return self._result(self._pose, odom_pose, None)
        found = self._track(predicted, points)
        if resumed is not None:
            # the odometry moved again after a stall: also match around the anchored
            # prediction, and keep the better match
            self._counts.extra["stall_resumed"] = self._counts.extra.get("stall_resumed", 0) + 1
            other = self._track(resumed, points)
            if other is not None and (found is None or other.score > found.score):
                self._counts.extra["stall_taken"] = self._counts.extra.get("stall_taken", 0) + 1
                found, predicted = other, resumed
        pose = found.pose if found is not None else predicted
        last = len(self._keys) - 1
        rel = between(self._graph.pose(last), pose)
        if math.hypot(rel[0], rel[1]) >= self.config.key_distance or \
                abs(rel[2]) >= self.config.key_angle:
            self._add_key(pose, points, odom_pose, stamp, found)
            self._record(stamp, len(self._keys) - 1, IDENTITY)
            pose = compose(self._graph.pose(len(self._keys) - 1), self._rel_to_key)
        else:
            self._rel_to_key = rel
            self._record(stamp, last, rel)
        return self._result(pose, odom_pose, found)

    def _track(self, predicted: Pose2, points: np.ndarray) -> Match | None:
        if len(points) < 10:
            return None
        if self._submap is None:
            self._submap_age = 0
            self._submap = self._field_of(range(max(0, len(self._keys) - self.config.submap_keys),
                                                len(self._keys)))
        cfg = self.config
        lin, ang = cfg.track_window
        sigmas = self._prediction_sigmas()
        weights = cfg.prior_weights
        if sigmas is not None:
            scale = cfg.score_sigma ** 2 / cfg.prior_points
            weights = (scale / sigmas[0] ** 2, scale / sigmas[1] ** 2)
        found = match(self._submap, points, predicted, windows(lin, ang, cfg.match_resolution),
                      cfg.score_sigma, penalty=cfg.search_penalty, prior_weights=weights,
                      tolerance=cfg.refine_tolerance, prior_sigmas=sigmas)
        if cfg.min_score <= found.score < cfg.weak_score and self._implausible(predicted, found):
            # a weak match (clutter, people, little structure) that moves the pose further
            # from the prediction than matches here usually do: the odometry is kept
            self._counts.extra["weak_refused"] = self._counts.extra.get("weak_refused", 0) + 1
            return None
        if found.score >= cfg.min_score:
            shift = between(predicted, found.pose)
            self._corrections.append((math.hypot(shift[0], shift[1]), abs(shift[2])))
            if len(self._corrections) > cfg.prior_window:
                del self._corrections[0]
        return found if found.score >= self.config.min_score else None

    def _implausible(self, predicted: Pose2, found: Match) -> bool:
        """Whether the match corrects the prediction by more than ``weak_gate`` x the median
        correction of the recent matches, in translation or in rotation."""
        cfg = self.config
        if len(self._corrections) < cfg.prior_window // 4:
            return False
        shifts = np.asarray(self._corrections)
        shift = between(predicted, found.pose)
        return (math.hypot(shift[0], shift[1]) > max(
            0.01, cfg.weak_gate * float(np.median(shifts[:, 0])))
            or abs(shift[2]) > max(math.radians(0.25),
                                   cfg.weak_gate * float(np.median(shifts[:, 1]))))

    def _prediction_sigmas(self) -> tuple[float, float] | None:
        """How far off the odometry prediction typically is, learnt from the last matches:
        ``prior_scale`` x the median correction (None until there are enough matches, or
        with prior_scale = 0)."""
        cfg = self.config
        if cfg.prior_scale <= 0 or len(self._corrections) < cfg.prior_window // 4:
            return None
        shifts = np.asarray(self._corrections)
        return (max(0.005, cfg.prior_scale * float(np.median(shifts[:, 0]))),
                max(math.radians(0.1), cfg.prior_scale * float(np.median(shifts[:, 1]))))

    def _field_of(self, keys: range | list[int], centre: Pose2 | None = None,
                  radius: float = math.inf, resolution: float = 0.0) -> DistanceField:
        """The distance field of key scans at their graph poses (only their points within
        ``radius`` of ``centre``, if given)."""
        world = [transform_points(self._graph.pose(k), self._keys[k].points) for k in keys]
        points = np.vstack(world) if world else np.zeros((0, 2))
        if centre is not None and math.isfinite(radius):
            points = points[np.hypot(points[:, 0] - centre[0], points[:, 1] - centre[1])
                            <= radius]
        return DistanceField.from_points(points, resolution or self.config.match_resolution,
                                         self.config.field_max_distance + 0.5,
                                         self.config.field_max_distance)

    def _add_key(self, pose: Pose2, points: np.ndarray, odom_pose: Pose2, stamp: float,
                 found: Match | None) -> None:
        travelled = 0.0
        if self._keys:
            prev = self._graph.pose(len(self._keys) - 1)
            travelled = self._keys[-1].travelled + math.hypot(pose[0] - prev[0],
                                                              pose[1] - prev[1])
        index = self._graph.add_node(pose)
        self._keys.append(KeyScan(points.astype(np.float32), odom_pose, stamp, travelled))
        self._rel_to_key = IDENTITY
        if index > 0:
            sigmas = self.config.match_sigmas if found is not None else self.config.odometry_sigmas
            self._graph.add_edge(index - 1, index, between(self._graph.pose(index - 1), pose),
                                 sigmas)
        anchor = self._atlas.anchor_key()
        self._atlas.add_key(index, pose, None if anchor is None else self._graph.pose(anchor),
                            points)
        self._submap_age += 1
        if self._submap_age >= self.config.submap_every:
            self._submap = None
        if self.config.loop_closure:
            self._close_loop(index)
        self._maybe_optimize(index)

    def _maybe_optimize(self, index: int) -> None:
        every = self.config.optimize_every
        if self._pending_loops and every > 0 and index - self._first_pending_key >= every:
            self.optimize()

    def _close_loop(self, index: int) -> None:
        cfg = self.config
        if index - self._last_loop_key < cfg.loop_every or len(self._keys[index].points) < 20:
            return
        candidate = self._loop_candidate(index)
        if candidate is None:
            return
        self._counts.loop_attempts += 1
        here = self._keys[index].travelled
        lo = max(0, candidate - cfg.loop_submap_keys)
        hi = min(index, candidate + cfg.loop_submap_keys + 1)
        near = [k for k in range(lo, hi) if here - self._keys[k].travelled >= cfg.loop_min_travel]
        submap = self._field_of(near)
        pose = self._graph.pose(index)
        found = match(submap, self._keys[index].points.astype(np.float64), pose,
                      windows(cfg.loop_window[0], cfg.loop_window[1], cfg.match_resolution),
                      cfg.score_sigma, bounded=cfg.loop_bounded)
        if found.score < cfg.loop_min_score:
            return
        closure = (candidate, index, between(self._graph.pose(candidate), found.pose),
                   compose(found.pose, inverse(pose)))
        shift = between(pose, found.pose)
        if not self._plausible(shift, here):
            self._counts.extra["implausible_loops"] = self._counts.extra.get(
                "implausible_loops", 0) + 1
            return
        if math.hypot(shift[0], shift[1]) <= cfg.loop_trust[0] and \
                abs(shift[2]) <= cfg.loop_trust[1]:
            self._add_loop(closure)
            return
        # a large correction is taken only once a second closure nearby agrees with it
        held = self._held_loop
        self._held_loop = closure
        if held is None or index - held[1] > cfg.loop_confirm_keys:
            return
        disagree = between(compose(held[3], pose), compose(closure[3], pose))
        if math.hypot(disagree[0], disagree[1]) <= cfg.loop_confirm[0] and \
                abs(disagree[2]) <= cfg.loop_confirm[1]:
            self._add_loop(held)
            self._add_loop(closure)
            self._held_loop = None
            self._counts.extra["confirmed_loops"] = self._counts.extra.get(
                "confirmed_loops", 0) + 1

    def _plausible(self, shift: Pose2, travelled: float) -> bool:
        """Whether a loop closure's correction ``shift`` fits the drift possible over the path
        driven since the last accepted closure (``travelled``: the path length now)."""
        cfg = self.config
        since = max(0.0, travelled - self._anchored_at)
        return (math.hypot(shift[0], shift[1]) <= cfg.loop_drift[0] + cfg.loop_drift[1] * since
                and abs(shift[2]) <= cfg.loop_drift_angle[0] + cfg.loop_drift_angle[1] * since)

    def _add_loop(self, closure: tuple[int, int, Pose2, Pose2]) -> None:
        candidate, index, relative, _ = closure
        self._anchored_at = max(self._anchored_at, self._keys[index].travelled)
        self._graph.add_edge(candidate, index, relative, self.config.loop_sigmas, robust=True)
        self._counts.loop_closures += 1
        if not self._pending_loops:
            self._first_pending_key = index
        self._pending_loops += 1
        self._last_loop_key = index

    def _loop_candidate(self, index: int) -> int | None:
        """The key scan nearest to key ``index`` among those far enough back along the path."""
        cfg = self.config
        here = self._keys[index].travelled
        old = [k for k in range(index) if here - self._keys[k].travelled >= cfg.loop_min_travel]
        if not old:
            return None
        positions = self._graph.poses[old, :2]
        gaps = np.hypot(*(positions - self._graph.poses[index, :2]).T)
        best = int(np.argmin(gaps))
        return old[best] if gaps[best] <= cfg.loop_search_radius else None
