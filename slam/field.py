# Truncated Euclidean distance field of a set of occupied points, with smooth lookups for matching.
from __future__ import annotations

import math

import numpy as np

from slam.grid import OccupancyGrid

SEARCH_PAD = 80  # zero-likelihood border cells around a field; searches reach at most half of it


class DistanceField:
    """Distance (m, truncated at ``max_distance``) from each cell centre to the nearest occupied
    cell, over a window that covers the points plus ``margin``; cell (0, 0)'s lower-left corner
    is at (origin_x, origin_y). Lookups outside read ``max_distance`` with zero gradient."""

    def __init__(self, occupied: np.ndarray, origin_x: float, origin_y: float,
                 resolution: float, max_distance: float,
                 exact_xy: np.ndarray | None = None) -> None:
        """``exact_xy`` (2, H, W): where in its cell each occupied cell's point really is
        (world m); distances are then measured to those points rather than to cell centres,
        which keeps the field free of the half-cell quantisation bias."""
        self.resolution = resolution
        self.origin_x, self.origin_y = origin_x, origin_y
        self.max_distance = max_distance
        self.height, self.width = occupied.shape
        from scipy import ndimage  # here, not at import: the daemon starts without scipy

        if not occupied.any():
            dist = np.full(occupied.shape, max_distance)
        elif exact_xy is None:
            dist = ndimage.distance_transform_edt(~occupied) * resolution
        else:
            rows, cols = ndimage.distance_transform_edt(~occupied, return_distances=False,
                                                        return_indices=True)
            cx = origin_x + (np.arange(self.width) + 0.5) * resolution
            cy = origin_y + (np.arange(self.height) + 0.5) * resolution
            dist = np.hypot(exact_xy[0][rows, cols] - cx[None, :],
                            exact_xy[1][rows, cols] - cy[:, None])
        self.distance = np.minimum(dist, max_distance).astype(np.float32)
        self._likelihood: dict[float, np.ndarray] = {}
        self._table: np.ndarray | None = None
        self._table_last = np.zeros((2, 1))

    @classmethod
    def from_points(cls, world_xy: np.ndarray, resolution: float, margin: float,
                    max_distance: float) -> DistanceField:
        """The field of world points (N, 2) on a window around them."""
        points = np.asarray(world_xy, dtype=np.float64).reshape(-1, 2)
        if len(points) == 0:
            points = np.zeros((1, 2))
        low = points.min(axis=0) - margin
        size = np.ceil((points.max(axis=0) + margin - low) / resolution).astype(int) + 1
        cells = np.floor((points - low) / resolution).astype(np.int64)
        flat = cells[:, 1] * size[0] + cells[:, 0]
        count = np.bincount(flat, minlength=size[0] * size[1]).reshape(size[1], size[0])
        occupied = count > 0
        exact = np.stack([np.bincount(flat, points[:, k], size[0] * size[1]).reshape(
            size[1], size[0]) / np.maximum(count, 1) for k in (0, 1)])
        return cls(occupied, float(low[0]), float(low[1]), resolution, max_distance, exact)

    @classmethod
    def from_grid(cls, grid: OccupancyGrid, max_distance: float,
                  threshold: int = 65) -> DistanceField:
        """The field of a grid's occupied cells (a fixed map for localisation)."""
        occupied = grid.occupancy() >= threshold
        return cls(occupied, grid.origin_x, grid.origin_y, grid.resolution, max_distance)

    @property
    def cells(self) -> int:
        return self.width * self.height

    def lookup(self, world_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Bilinear distance and its gradient (d, dd/dx, dd/dy) at world points (N, 2)."""
        value, grad = self.lookup_cells(self.to_cells(world_xy))
        assert grad is not None
        scale = 1.0 / self.resolution
        return value, grad[0] * scale, grad[1] * scale

    def to_cells(self, world_xy: np.ndarray) -> np.ndarray:
        """World points (N, 2) in the units ``lookup_cells`` takes: (2, N), cells from the
        centre of the cell (-1, -1), i.e. (x - origin_x) / resolution + 0.5."""
        inv = 1.0 / self.resolution
        return np.stack([(world_xy[:, 0] - self.origin_x) * inv + 0.5,
                         (world_xy[:, 1] - self.origin_y) * inv + 0.5])

    def lookup_cells(self, uv: np.ndarray,
                     gradient: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Bilinear distance (m) at points ``uv`` (2, N) in the units of ``to_cells``, and
        (``gradient``) its gradient in m per cell (2, N): one gather of the bilinear table a
        point, no bounds masks. Outside the field: max_distance, zero gradient."""
        table = self._bilinear()
        whole = np.floor(uv)
        frac = uv - whole
        # cells outside [0, width - 1) x [0, height - 1) read the table's border:
        # max_distance, zero gradient
        np.maximum(whole, 0.0, out=whole)
        np.minimum(whole, self._table_last, out=whole)
        cell = whole.astype(np.intp)
        coef = table[:, cell[1] * (self.width + 1) + cell[0]]
        a, b, c, e = coef
        fu, fv = frac
        across = c + e * fu
        value = a + b * fu + across * fv
        if not gradient:
            return value, None
        grad = np.empty_like(uv)
        np.multiply(e, fv, out=grad[0])
        grad[0] += b
        grad[1] = across
        return value, grad

    def _bilinear(self) -> np.ndarray:
        """(4, cells): per cell (r, c) of [-1, height - 1] x [-1, width - 1], flattened
        row-major, the coefficients (a, b, c, e) of d(fu, fv) = a + b fu + c fv + e fu fv
        between the centres of cells (r, c) .. (r + 1, c + 1); the border rows and columns
        hold (max_distance, 0, 0, 0)."""
        if self._table is None:
            d = self.distance.astype(np.float64)
            table = np.zeros((4, self.height + 1, self.width + 1))
            table[0] = self.max_distance
            if self.height > 1 and self.width > 1:
                d00, d01, d10, d11 = d[:-1, :-1], d[:-1, 1:], d[1:, :-1], d[1:, 1:]
                table[0, 1:-1, 1:-1] = d00
                table[1, 1:-1, 1:-1] = d01 - d00
                table[2, 1:-1, 1:-1] = d10 - d00
                table[3, 1:-1, 1:-1] = d11 - d10 - d01 + d00
            self._table = table.reshape(4, -1)
            self._table_last = np.array([[self.width], [self.height]], dtype=np.float64)
        return self._table

    def likelihood(self, sigma: float) -> np.ndarray:
        """exp(-d² / 2 sigma²) per cell, float32, inside a border of SEARCH_PAD zero cells on
        every side (so searches index it without bounds checks); cached per sigma."""
        key = round(sigma, 6)
        if key not in self._likelihood:
            scale = np.float32(-1.0 / (2 * sigma * sigma))
            padded = np.zeros((self.height + 2 * SEARCH_PAD, self.width + 2 * SEARCH_PAD),
                              dtype=np.float32)
            inner = padded[SEARCH_PAD:-SEARCH_PAD, SEARCH_PAD:-SEARCH_PAD]
            np.exp(self.distance * self.distance * scale, out=inner)
            self._likelihood[key] = padded
        return self._likelihood[key]

    def score(self, world_xy: np.ndarray, sigma: float) -> float:
        """Mean likelihood of the points under the bilinear distance: 0 (nothing fits) .. 1."""
        if len(world_xy) == 0:
            return 0.0
        d, _ = self.lookup_cells(self.to_cells(world_xy), gradient=False)
        return float(np.mean(np.exp(d * d * (-1.0 / (2 * sigma * sigma)))))

    def contains(self, x: float, y: float) -> bool:
        col = math.floor((x - self.origin_x) / self.resolution)
        row = math.floor((y - self.origin_y) / self.resolution)
        return 0 <= col < self.width and 0 <= row < self.height
