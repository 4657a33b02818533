# A rolling-free occupancy costmap built from scans: evidence per cell, inflated traversal costs.
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: evidence a lidar return adds to its cell, and a ray passing through takes away
HIT, MISS = 4, 1
#: evidence bounds (a cell seen free many times still turns occupied after a few hits)
EVIDENCE_MIN, EVIDENCE_MAX = -8, 16
#: evidence from which a cell counts as an obstacle
OCCUPIED = 2
#: costs are worked out on cells at least this big (m): finer grids are pooled for it (an
#: obstacle anywhere in a pooled cell counts for the whole cell)
DISTANCE_CELL_M = 0.1


@dataclass(frozen=True)
class CostParams:
    """How cells cost: ``radius_m`` the robot's reach (cells nearer an obstacle are lethal),
    ``inflation_m`` the band beyond it where cost decays from ``inflation_cost`` to 0,
    ``unknown_cost`` the extra cost of an unseen cell; 1 is the cost of a free metre.
    ``line_margin_m``: a path's straightened stretches keep this far past the reach (or as
    far as the grid path they replace)."""

    radius_m: float
    inflation_m: float = 0.5
    inflation_cost: float = 3.0
    unknown_cost: float = 1.0
    line_margin_m: float = 0.3

    def band_cost(self, beyond_m: float) -> float:
        """The cost of a seen cell ``beyond_m`` past the reach (1 past the band)."""
        if self.inflation_m <= 0:
            return 1.0
        band = min(max(1.0 - beyond_m / self.inflation_m, 0.0), 1.0)
        return 1.0 + self.inflation_cost * band ** 2

    @property
    def line_cost(self) -> float:
        """The dearest cell a straightened stretch may cross (see ``line_margin_m``)."""
        return self.band_cost(self.line_margin_m)


@dataclass(frozen=True)
class GridArea:
    """Where the grid lies: cell size (m), lower-left corner (m), cells per side."""

    resolution: float
    origin_x: float
    origin_y: float
    width: int
    height: int

    def cell(self, x: float, y: float) -> tuple[int, int]:
        """``(row, col)`` of the point (may lie outside the grid)."""
        return (math.floor((y - self.origin_y) / self.resolution),
                math.floor((x - self.origin_x) / self.resolution))

    def inside(self, row: int, col: int) -> bool:
        return 0 <= row < self.height and 0 <= col < self.width

    def centre(self, row: int, col: int) -> tuple[float, float]:
        return (self.origin_x + (col + 0.5) * self.resolution,
                self.origin_y + (row + 0.5) * self.resolution)


def centred_area(resolution: float, size_m: float, x: float = 0.0, y: float = 0.0) -> GridArea:
    """A square grid of ``size_m`` side centred on (x, y)."""
    cells = max(1, math.ceil(size_m / resolution))
    half = cells * resolution / 2
    return GridArea(resolution, x - half, y - half, cells, cells)


class Costmap:
    """Evidence of obstacles per cell from lidar revolutions (returns add, rays clear) and the
    cost of crossing each cell for the planner."""

    def __init__(self, area: GridArea, params: CostParams,
                 cells: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """``cells``: the evidence (int8) and seen (bool) arrays to work in, (height, width)
        each and zeroed (e.g. in memory shared with a worker process); by default its own."""
        self.area = area
        self.params = params
        shape = (area.height, area.width)
        if cells is None:
            cells = np.zeros(shape, dtype=np.int8), np.zeros(shape, dtype=bool)
        self.evidence, self.seen = cells
        if self.evidence.shape != shape or self.seen.shape != shape \
                or self.evidence.dtype != np.int8 or self.seen.dtype != np.bool_:
            raise ValueError(f"costmap cells must be int8 and bool arrays of shape {shape}")

    def add_scan(self, pose: tuple[float, float, float], xs: np.ndarray, ys: np.ndarray) -> None:
        """One revolution's returns (robot frame) taken at ``pose`` (the grid's frame)."""
        if len(xs) == 0:
            return
        px, py, theta = pose
        c, s = math.cos(theta), math.sin(theta)
        hx, hy = px + c * xs - s * ys, py + s * xs + c * ys
        res = self.area.resolution
        lengths = np.hypot(hx - px, hy - py)
        samples = int(np.ceil(lengths.max() / (0.5 * res)))
        f = (np.arange(samples) / max(samples, 1))[None, :]
        keep = f * lengths[:, None] < (lengths[:, None] - res)
        rx = (px + f * (hx - px)[:, None])[keep]
        ry = (py + f * (hy - py)[:, None])[keep]
        free = self._flat(rx, ry)
        hits = self._flat(hx, hy)
        counts = np.bincount(free, minlength=self.evidence.size)
        counts[hits] = 0  # a return beats the rays of the same revolution
        flat = self.evidence.reshape(-1)
        touched = np.nonzero(counts)[0]
        value = flat[touched].astype(np.int16) - MISS
        flat[touched] = np.clip(value, EVIDENCE_MIN, EVIDENCE_MAX)
        value = flat[hits].astype(np.int16) + HIT
        flat[hits] = np.clip(value, EVIDENCE_MIN, EVIDENCE_MAX)
        seen = self.seen.reshape(-1)
        seen[touched] = True
        seen[hits] = True

    def _flat(self, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        area = self.area
        cols = np.floor((xs - area.origin_x) / area.resolution).astype(np.int64)
        rows = np.floor((ys - area.origin_y) / area.resolution).astype(np.int64)
        inside = (cols >= 0) & (cols < area.width) & (rows >= 0) & (rows < area.height)
        return np.unique(rows[inside] * area.width + cols[inside])

    def mark_occupied(self, occupied: np.ndarray) -> None:
        """Cells known occupied from elsewhere (a map): set as obstacles and seen."""
        self.evidence[occupied] = EVIDENCE_MAX
        self.seen |= occupied

    def obstacles(self) -> np.ndarray:
        return self.evidence >= OCCUPIED

    def costs(self) -> np.ndarray:
        """Cost of crossing each cell per metre: 1 in free space, more near obstacles and in
        unseen cells, ``inf`` where the robot's centre cannot be (float32)."""
        return cost_grid(self.obstacles(), self.seen, self.area.resolution, self.params)


def cost_grid(obstacles: np.ndarray, seen: np.ndarray, resolution: float,
              params: CostParams) -> np.ndarray:
    """The traversal cost of every cell (see :meth:`Costmap.costs`). On a grid finer than
    DISTANCE_CELL_M the costs are worked out on pooled cells (an obstacle or a sighting
    anywhere in one counts for all of it) and spread back onto the cells."""
    pool = max(1, int(DISTANCE_CELL_M / resolution + 1e-9))
    shrink = (pool - 1) * resolution * math.sqrt(2.0)
    # distances beyond the footprint's reach and the band all cost the same: not worked out
    reach = params.radius_m + max(params.inflation_m, 0.0) + shrink
    limit = math.ceil(reach / (pool * resolution)) + 1
    if pool == 1:
        return _costs(obstacle_distance(obstacles, limit), seen, resolution, 0.0, params)
    h, w = obstacles.shape
    coarse = _costs(obstacle_distance(pool_any(obstacles, pool), limit), pool_any(seen, pool),
                    pool * resolution, shrink, params)
    return np.repeat(np.repeat(coarse, pool, axis=0), pool, axis=1)[:h, :w]


def _costs(cells: np.ndarray, seen: np.ndarray, resolution: float, shrink: float,
           params: CostParams) -> np.ndarray:
    """Costs from the distance to the nearest obstacle in cells, cut by ``shrink`` metres
    (how much nearer a point of a pooled cell can be than its centre)."""
    distance = np.maximum(cells * resolution - shrink, 0.0)
    beyond = np.maximum(distance - params.radius_m, 0.0)
    band = np.clip(1.0 - beyond / params.inflation_m, 0.0, 1.0) if params.inflation_m > 0 \
        else np.zeros(cells.shape)
    costs = (1.0 + params.inflation_cost * band ** 2).astype(np.float32)
    costs[~seen] += np.float32(params.unknown_cost)
    costs[distance <= params.radius_m] = np.inf
    return costs


def obstacle_distance(obstacles: np.ndarray, limit: int | None = None) -> np.ndarray:
    """Distance from each cell to the nearest obstacle cell, in cells (``inf`` without any).
    With ``limit``, exact up to ``limit`` cells and only said to be more than it beyond (a
    few vectorised passes instead of a whole Euclidean transform: the costs need no more)."""
    if not obstacles.any():
        return np.full(obstacles.shape, np.inf)
    if limit is None:
        from scipy import ndimage  # here, not at import: the daemon starts without scipy

        return np.asarray(ndimage.distance_transform_edt(~obstacles))
    # along each row: the distance to the nearest obstacle of that row (capped past limit)
    h, w = obstacles.shape
    far = 2 * (w + limit + 1)
    cols = np.arange(w)
    left = np.maximum.accumulate(np.where(obstacles, cols, -far), axis=1)
    right = np.minimum.accumulate(np.where(obstacles, cols, far)[:, ::-1], axis=1)[:, ::-1]
    along = np.minimum(np.minimum(cols - left, right - cols), limit + 1).astype(np.float32)
    # then across rows: the nearest of the rows within limit (a nearer obstacle cannot lie
    # farther away than that)
    squares = along * along
    best = squares.copy()
    for dr in range(1, min(limit, h - 1) + 1):
        step = np.float32(dr * dr)
        np.minimum(best[dr:], squares[:-dr] + step, out=best[dr:])
        np.minimum(best[:-dr], squares[dr:] + step, out=best[:-dr])
    return np.sqrt(best.astype(np.float64))  # as the exact transform's


def pool_any(cells: np.ndarray, pool: int) -> np.ndarray:
    """Blocks of ``pool`` x ``pool`` cells, set where any of their cells is (edges padded)."""
    h, w = cells.shape
    padded = np.zeros((-(-h // pool) * pool, -(-w // pool) * pool), dtype=bool)
    padded[:h, :w] = cells
    out = padded[::pool, ::pool].copy()
    for dr in range(pool):
        for dc in range(pool):
            out |= padded[dr::pool, dc::pool]
    return out
