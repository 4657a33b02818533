# Log-odds occupancy grid that grows as the robot explores, bounded by a cell budget.
from __future__ import annotations

import math

import numpy as np

from slam.pose import Pose2, transform_points

UNKNOWN = -1
# log-odds never rests at exactly 0 once observed: 0 means "never observed" (unknown)
OBSERVED_EPSILON = np.float32(1e-4)


class OccupancyGrid:
    """log-odds occupancy grid, y up, row-major from origin; grows as the robot explores, bounded.

    ``log_odds[row, col]`` covers the world square whose lower-left corner is
    ``(origin_x + col * resolution, origin_y + row * resolution)``. A cell is unknown while its
    log-odds is exactly 0; every observed cell is kept away from 0.

    Growth: when a scan reaches outside the grid, the grid is enlarged to cover it plus a
    margin (``growth_margin`` metres, at least half the current size, so growth is amortised).
    Bound: the area never exceeds ``max_cells``; rays whose end point would fall beyond that
    bound are dropped and counted in ``dropped_points``. Memory is 4 bytes a cell (float32):
    a 40 x 40 m map at 0.05 m is 640 000 cells, 2.56 MB (plus 0.64 MB for an ``occupancy()``
    rendering); the default bound of 4 000 000 cells is 16 MB (100 x 100 m at 0.05 m).
    """

    def __init__(self, resolution: float = 0.05, max_cells: int = 4_000_000, *,
                 initial_size: float = 10.0, growth_margin: float = 5.0,
                 hit_log_odds: float = 0.9, miss_log_odds: float = -0.4,
                 min_log_odds: float = -5.0, max_log_odds: float = 5.0) -> None:
        if resolution <= 0 or max_cells < 1:
            raise ValueError("resolution must be > 0 and max_cells >= 1")
        self.resolution = float(resolution)
        self.max_cells = int(max_cells)
        self.growth_margin = float(growth_margin)
        self.hit_log_odds = np.float32(hit_log_odds)
        self.miss_log_odds = np.float32(miss_log_odds)
        self.min_log_odds = np.float32(min_log_odds)
        self.max_log_odds = np.float32(max_log_odds)
        side = max(1, min(math.ceil(initial_size / resolution), math.isqrt(self.max_cells)))
        self.width = side
        self.height = side
        self.origin_x = -side * resolution / 2
        self.origin_y = -side * resolution / 2
        self.log_odds = np.zeros((side, side), dtype=np.float32)
        self.version = 0
        self.dropped_points = 0

    # ------------------------------------------------------------------ geometry

    def cell_of(self, world_xy: np.ndarray) -> np.ndarray:
        """Integer (col, row) of world points (N, 2); may lie outside the grid."""
        offset = np.array([self.origin_x, self.origin_y])
        return np.floor((np.asarray(world_xy) - offset) / self.resolution).astype(np.int64)

    def _inside(self, cells: np.ndarray) -> np.ndarray:
        return ((cells[:, 0] >= 0) & (cells[:, 0] < self.width)
                & (cells[:, 1] >= 0) & (cells[:, 1] < self.height))

    @property
    def nbytes(self) -> int:
        return int(self.log_odds.nbytes)

    # ------------------------------------------------------------------ growth

    def _grow_to_cover(self, world_xy: np.ndarray) -> None:
        """Enlarge (bounded by max_cells) so that the points fall inside, with a margin."""
        cells = self.cell_of(world_xy)
        lo = np.minimum(cells.min(axis=0), 0)
        hi = np.maximum(cells.max(axis=0) + 1, (self.width, self.height))
        if lo[0] == 0 and lo[1] == 0 and hi[0] == self.width and hi[1] == self.height:
            return
        margin = max(round(self.growth_margin / self.resolution), max(self.width, self.height) // 2)
        need_lo = np.where(lo < 0, lo - margin, 0)
        need_hi = np.where(hi > (self.width, self.height), hi + margin, (self.width, self.height))
        need_lo, need_hi = self._fit_budget(need_lo, need_hi, lo, hi)
        self._reshape(int(need_lo[0]), int(need_lo[1]), int(need_hi[0]), int(need_hi[1]))

    def cover(self, world_xy: np.ndarray) -> None:
        """Grow (bounded by max_cells, with the usual margin) to cover these world points."""
        self._grow_to_cover(np.asarray(world_xy, dtype=np.float64).reshape(-1, 2))

    def cropped(self) -> OccupancyGrid:
        """A copy cut down to the observed cells (cell boundaries unchanged); one cell if none
        is observed."""
        rows = np.flatnonzero(self.log_odds.any(axis=1))
        cols = np.flatnonzero(self.log_odds.any(axis=0))
        twin = self.copy()
        if not len(rows):
            rows = cols = np.zeros(1, dtype=np.int64)
        r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        twin.log_odds = self.log_odds[r0:r1, c0:c1].copy()
        twin.height, twin.width = r1 - r0, c1 - c0
        twin.origin_x = self.origin_x + c0 * self.resolution
        twin.origin_y = self.origin_y + r0 * self.resolution
        return twin

    def _fit_budget(self, need_lo: np.ndarray, need_hi: np.ndarray, lo: np.ndarray,
                    hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Shrink a growth request until its area fits max_cells (margin first, then coverage)."""
        current = np.array([self.width, self.height])

        def area(a: np.ndarray, b: np.ndarray) -> int:
            return int(np.prod(b - a))

        if area(need_lo, need_hi) <= self.max_cells:
            return need_lo, need_hi
        if area(lo, hi) <= self.max_cells:
            return lo, hi
        low, high = 0.0, 1.0  # fraction of the extension beyond the current grid that is kept
        for _ in range(30):
            mid = (low + high) / 2
            a = np.floor(lo * mid).astype(np.int64)
            b = current + np.ceil((hi - current) * mid).astype(np.int64)
            if area(a, b) <= self.max_cells:
                low = mid
            else:
                high = mid
        return (np.floor(lo * low).astype(np.int64),
                current + np.ceil((hi - current) * low).astype(np.int64))

    def _reshape(self, col0: int, row0: int, col1: int, row1: int) -> None:
        """New extent [col0, col1) x [row0, row1) in current cell coordinates (col0, row0 <= 0)."""
        grown = np.zeros((row1 - row0, col1 - col0), dtype=np.float32)
        grown[-row0:-row0 + self.height, -col0:-col0 + self.width] = self.log_odds
        self.log_odds = grown
        self.origin_x += col0 * self.resolution
        self.origin_y += row0 * self.resolution
        self.width, self.height = col1 - col0, row1 - row0
        self.version += 1

    # ------------------------------------------------------------------ update

    def integrate(self, pose: Pose2, points_xy: np.ndarray) -> None:
        """Points in the pose's frame (N, 2); rays from the pose origin: free along, occupied at
        the end. Each cell changes at most once per call for each of free and occupied."""
        points = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
        if len(points) == 0:
            return
        ends = transform_points(pose, points)
        origin = np.array(pose[:2])
        self._grow_to_cover(np.vstack([ends, origin[None, :]]))
        end_cells = self.cell_of(ends)
        keep = self._inside(end_cells)
        self.dropped_points += int(np.count_nonzero(~keep))
        ends, end_cells = ends[keep], end_cells[keep]
        if len(ends) == 0:
            return
        free = self._free_cells(origin, ends, end_cells)
        flat = self.log_odds.reshape(-1)
        self._add(flat, free, self.miss_log_odds)
        self._add(flat, end_cells[:, 1] * self.width + end_cells[:, 0], self.hit_log_odds)
        self.version += 1

    def _free_cells(self, origin: np.ndarray, ends: np.ndarray,
                    end_cells: np.ndarray) -> np.ndarray:
        """Flat indices of the cells the rays cross before their end cell (repeats allowed):
        samples every half cell along each ray, as many as that ray's length needs (the rays
        are ragged, flattened ray after ray: short rays cost no padding to the longest)."""
        step = self.resolution * 0.5
        delta = ends - origin
        length = np.hypot(delta[:, 0], delta[:, 1])
        # samples k * step with k * step < length: one more k than needed, the test below
        # drops it (the same samples as a rectangle padded to the longest ray)
        counts = np.ceil(length / step).astype(np.int64) + 1
        total = int(counts.sum())
        ray = np.repeat(np.arange(len(counts)), counts)
        starts = np.cumsum(counts) - counts
        t = (np.arange(total) - np.repeat(starts, counts)) * step  # metres along the ray
        frac = t / np.maximum(length[ray], 1e-9)
        keep = frac < 1.0
        xs = origin[0] + delta[ray, 0] * frac
        ys = origin[1] + delta[ray, 1] * frac
        cols = np.floor((xs - self.origin_x) / self.resolution).astype(np.int64)
        rows = np.floor((ys - self.origin_y) / self.resolution).astype(np.int64)
        keep &= ~((cols == end_cells[ray, 0]) & (rows == end_cells[ray, 1]))
        keep &= (cols >= 0) & (cols < self.width) & (rows >= 0) & (rows < self.height)
        return (rows[keep] * self.width + cols[keep]).astype(np.int64)

    def _add(self, flat: np.ndarray, index: np.ndarray, amount: np.float32) -> None:
        """Add once per distinct cell (fancy assignment writes repeats once), clamp, keep != 0."""
        updated = np.clip(flat[index] + amount, self.min_log_odds, self.max_log_odds)
        updated[updated == 0] = OBSERVED_EPSILON
        flat[index] = updated

    # ------------------------------------------------------------------ views

    def occupancy(self) -> np.ndarray:
        """int8 (height, width): -1 unknown, 0..100 (nav_msgs/OccupancyGrid semantics).
        Cells at the log-odds bounds read 0 and 100."""
        lo = self.log_odds
        prob = np.rint(100.0 / (1.0 + np.exp(-lo.astype(np.float64)))).astype(np.int8)
        prob[lo <= self.min_log_odds] = 0
        prob[lo >= self.max_log_odds] = 100
        prob[lo == 0] = UNKNOWN
        return prob

    @classmethod
    def from_occupancy(cls, occ: np.ndarray, resolution: float, origin_x: float,
                       origin_y: float) -> OccupancyGrid:
        """A grid from nav_msgs-style values (-1 unknown, 0..100); ``occupancy()`` gives them
        back exactly."""
        values = np.asarray(occ)
        if values.ndim != 2:
            raise ValueError(f"occupancy must be 2-D, got shape {values.shape}")
        if values.size and (values.min() < -1 or values.max() > 100):
            raise ValueError("occupancy values must be -1 or 0..100")
        grid = cls(resolution, max_cells=max(4_000_000, values.size), initial_size=resolution)
        prob = np.clip(values.astype(np.float64), 1, 99) / 100.0
        lo = np.log(prob / (1.0 - prob)).astype(np.float32)
        lo[lo == 0] = OBSERVED_EPSILON
        lo[values == 0] = grid.min_log_odds
        lo[values == 100] = grid.max_log_odds
        lo[values == UNKNOWN] = 0.0
        grid.log_odds = lo
        grid.height, grid.width = values.shape
        grid.origin_x, grid.origin_y = float(origin_x), float(origin_y)
        return grid

    def copy(self) -> OccupancyGrid:
        twin = OccupancyGrid.__new__(OccupancyGrid)
        twin.__dict__.update(self.__dict__)
        twin.log_odds = self.log_odds.copy()
        return twin

    def occupied_points(self, threshold: int = 65) -> np.ndarray:
        """World coordinates (N, 2) of the centres of cells at or above ``threshold`` percent."""
        occ = self.occupancy()
        rows, cols = np.nonzero(occ >= threshold)
        return np.column_stack([self.origin_x + (cols + 0.5) * self.resolution,
                                self.origin_y + (rows + 0.5) * self.resolution])
