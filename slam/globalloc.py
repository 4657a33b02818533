# Global localisation: where one scan fits anywhere on a saved map, or "ambiguous" if it fits twice.
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from slam.field import DistanceField
from slam.grid import OccupancyGrid
from slam.matcher import SearchWindow, match, subsample
from slam.pose import Pose2, transform_points, wrap

FOUND, AMBIGUOUS, NOT_FOUND = "found", "ambiguous", "not_found"


@dataclass(frozen=True)
class GlobalConfig:
    """Tunables of the global search (lengths in m, angles in rad).

    step, turn: the lattice of poses scored exhaustively over the map's free space.
    sigma: width of the coarse likelihood, max-filtered over one ``step`` so that a lattice
        pose bounds every pose in its square (the first level of a branch and bound).
    points: the scan is subsampled to this many points for the exhaustive level.
    clearance: a pose lies at least this far from the map's walls (the robot's body).
    shortlist: the best lattice poses, distinct by ``distinct``, refined by a correlative
        search and Gauss-Newton on the map's distance field.
    accept: a refined pose needs at least this score (0..1, after the free-space check).
    ambiguity: the pose is refused as ambiguous when a distinct candidate scores at least this
        share of the best's.
    """

    step: float = 0.25
    turn: float = math.radians(3.0)
    sigma: float = 0.15
    points: int = 64
    clearance: float = 0.12
    shortlist: int = 16
    distinct: tuple[float, float] = (0.6, math.radians(20))
    accept: float = 0.55
    ambiguity: float = 0.9
    score_sigma: float = 0.05
    refine_window: tuple[float, float] = (0.2, math.radians(3.5))


@dataclass(frozen=True)
class GlobalResult:
    """``status`` found (``pose`` is the answer), ambiguous (the best ``candidates`` fit about
    equally well) or not_found (nothing fits well enough); candidates: (pose, score), best
    first."""

    status: str
    pose: Pose2 | None
    score: float
    candidates: tuple[tuple[Pose2, float], ...]


class GlobalLocalizer:
    """Precomputes, once per map, the coarse likelihood and the free positions; ``search`` then
    costs one pass over (positions x headings x points) plus a few refinements."""

    def __init__(self, grid: OccupancyGrid, fine: DistanceField,
                 config: GlobalConfig = GlobalConfig()) -> None:
        from scipy import ndimage  # here, not at import: the daemon starts without scipy

        self.config = config
        self.fine = fine
        occupancy = grid.occupancy()
        self.occupied = occupancy >= 65
        self.resolution = grid.resolution
        self.origin = (grid.origin_x, grid.origin_y)
        likelihood = np.exp(-(fine.distance.astype(np.float64) ** 2) / (2 * config.sigma ** 2))
        size = max(1, round(config.step / grid.resolution) + 1)
        self.bound = ndimage.maximum_filter(likelihood, size=size, mode="constant").astype(
            np.float32)
        self.positions = self._free_positions(occupancy)

    def _free_positions(self, occupancy: np.ndarray) -> np.ndarray:
        """Centres of lattice squares over known free cells clear of the walls (K, 2)."""
        cfg, res = self.config, self.resolution
        free = (occupancy >= 0) & (occupancy < 35) & (self.fine.distance >= cfg.clearance)
        stride = max(1, round(cfg.step / res))
        half = stride // 2
        rows, cols = np.nonzero(free[half::stride, half::stride])
        rows, cols = rows * stride + half, cols * stride + half
        return np.column_stack([self.origin[0] + (cols + 0.5) * res,
                                self.origin[1] + (rows + 0.5) * res])

    def search(self, points_xy: np.ndarray) -> GlobalResult:
        """The pose of a scan (points (N, 2) in the robot frame) on the whole map."""
        cfg = self.config
        points = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
        if len(points) < 20 or not len(self.positions):
            return GlobalResult(NOT_FOUND, None, 0.0, ())
        shortlist = self._shortlist(subsample(points, cfg.points))
        refined = [self._refine(points, pose) for pose in shortlist]
        ranked = _distinct(sorted(refined, key=lambda c: -c[1]), cfg.distinct)
        if not ranked or ranked[0][1] < cfg.accept:
            return GlobalResult(NOT_FOUND, None, ranked[0][1] if ranked else 0.0,
                                tuple(ranked[:5]))
        best = ranked[0]
        if len(ranked) > 1 and ranked[1][1] >= cfg.ambiguity * best[1]:
            close = tuple(c for c in ranked if c[1] >= cfg.ambiguity * best[1])
            return GlobalResult(AMBIGUOUS, None, best[1], close[:5])
        return GlobalResult(FOUND, best[0], best[1], tuple(ranked[:5]))

    def _shortlist(self, sparse: np.ndarray) -> list[Pose2]:
        """The best lattice poses by the bounded coarse score, distinct from each other."""
        cfg, res = self.config, self.resolution
        angles = np.arange(-math.pi, math.pi, cfg.turn)
        height, width = self.bound.shape
        best: list[tuple[float, int, int]] = []
        per_angle = max(cfg.shortlist * 4, 32)
        cx = (self.positions[:, 0] - self.origin[0]) / res
        cy = (self.positions[:, 1] - self.origin[1]) / res
        for a, theta in enumerate(angles):
            c, s = math.cos(theta), math.sin(theta)
            px = (c * sparse[:, 0] - s * sparse[:, 1]) / res
            py = (s * sparse[:, 0] + c * sparse[:, 1]) / res
            cols = np.floor(cx[:, None] + px[None, :]).astype(np.int64)
            rows = np.floor(cy[:, None] + py[None, :]).astype(np.int64)
            inside = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
            values = np.where(inside, self.bound[np.clip(rows, 0, height - 1),
                                                 np.clip(cols, 0, width - 1)], 0.0)
            scores = values.mean(axis=1)
            top = np.argpartition(-scores, min(per_angle, len(scores) - 1))[:per_angle]
            best.extend((float(scores[i]), a, int(i)) for i in top)
        best.sort(reverse=True)
        poses = [(float(self.positions[i, 0]), float(self.positions[i, 1]), float(angles[a]))
                 for _, a, i in best[: cfg.shortlist * 20]]
        kept: list[Pose2] = []
        for pose in poses:
            if all(not _same(pose, other, cfg.distinct) for other in kept):
                kept.append(pose)
                if len(kept) >= cfg.shortlist:
                    break
        return kept

    def _refine(self, points: np.ndarray, pose: Pose2) -> tuple[Pose2, float]:
        """A correlative search and Gauss-Newton around ``pose`` on the fine field, the score
        then scaled by the share of the scan's rays that do not cross a wall of the map."""
        cfg = self.config
        lin, ang = cfg.refine_window
        steps = (SearchWindow(lin, ang, 0.05, math.radians(1.0), 0.1),
                 SearchWindow(0.05, math.radians(1.0), self.resolution, math.radians(0.5),
                              0.05))
        found = match(self.fine, points, pose, steps, cfg.score_sigma, penalty=0.0)
        return found.pose, found.score * (1.0 - self._crossing(points, found.pose))

    def _crossing(self, points: np.ndarray, pose: Pose2) -> float:
        """Share of the rays to the scan's points that pass through a wall of the map on the
        way (sampled at 30, 55 and 80 % of their length)."""
        sparse = subsample(points, 120)
        inner = np.vstack([sparse * f for f in (0.3, 0.55, 0.8)])
        world = transform_points(pose, inner)
        res = self.resolution
        cols = np.floor((world[:, 0] - self.origin[0]) / res).astype(np.int64)
        rows = np.floor((world[:, 1] - self.origin[1]) / res).astype(np.int64)
        h, w = self.occupied.shape
        inside = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
        hits = np.zeros(len(world), dtype=bool)
        hits[inside] = self.occupied[rows[inside], cols[inside]]
        per_ray = hits.reshape(3, -1).any(axis=0)
        return float(per_ray.mean())


def _same(a: Pose2, b: Pose2, distinct: tuple[float, float]) -> bool:
    return (math.hypot(a[0] - b[0], a[1] - b[1]) < distinct[0]
            and abs(wrap(a[2] - b[2])) < distinct[1])


def _distinct(ranked: list[tuple[Pose2, float]],
              distinct: tuple[float, float]) -> list[tuple[Pose2, float]]:
    kept: list[tuple[Pose2, float]] = []
    for pose, score in ranked:
        if all(not _same(pose, other, distinct) for other, _ in kept):
            kept.append((pose, score))
    return kept
