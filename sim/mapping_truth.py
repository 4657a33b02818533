# Ground truth for judging maps and trajectories: rasterised walls, map scores, pose errors.
"""Pure helpers (numpy only, no I/O) that score a mapper against the simulated world.

Grids are ``bool`` arrays of shape ``(height, width)`` indexed ``[row, col]``: cell
``(row, col)`` covers ``origin_x + col * resolution`` .. ``+ resolution`` in x and
``origin_y + row * resolution`` .. ``+ resolution`` in y, so row 0 is the bottom row (the
layout of ``nav_msgs/OccupancyGrid.data`` reshaped to ``(height, width)``).
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from sim.raycast import RayCaster, ray_angles
from sim.world import Pose, World

#: Points per block when clearances are computed (bounds the temporary arrays).
CLEARANCE_BLOCK = 16384

PoseLike = Pose | Sequence[float]


@dataclass(frozen=True)
class GridSpec:
    """Where a grid lies in the world: cell size (m), lower-left corner (m), size (cells)."""

    resolution: float
    origin_x: float
    origin_y: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if not self.resolution > 0 or self.width < 1 or self.height < 1:
            raise ValueError(f"a grid needs resolution > 0 and at least one cell, got {self}")

    @property
    def shape(self) -> tuple[int, int]:
        return self.height, self.width

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """The x and y of every cell centre, each of shape ``(height, width)``."""
        xs = self.origin_x + (np.arange(self.width) + 0.5) * self.resolution
        ys = self.origin_y + (np.arange(self.height) + 0.5) * self.resolution
        grid_x, grid_y = np.meshgrid(xs, ys)
        return grid_x, grid_y

    def mark(self, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """A grid with the cells that contain any of the points set (points outside ignored)."""
        cols = np.floor((np.asarray(xs) - self.origin_x) / self.resolution).astype(np.int64)
        rows = np.floor((np.asarray(ys) - self.origin_y) / self.resolution).astype(np.int64)
        inside = (cols >= 0) & (cols < self.width) & (rows >= 0) & (rows < self.height)
        grid = np.zeros(self.shape, dtype=bool)
        grid[rows[inside], cols[inside]] = True
        return grid

    def cell_of(self, x: float, y: float) -> tuple[int, int]:
        """``(row, col)`` of the cell holding the point (may lie outside the grid)."""
        return (math.floor((y - self.origin_y) / self.resolution),
                math.floor((x - self.origin_x) / self.resolution))


def world_grid(world: World, resolution: float, margin: float = 0.0) -> GridSpec:
    """A grid over the bounding box of the world's walls and circles, grown by ``margin``."""
    seg, cir = world.segment_array, world.circle_array
    xs = np.concatenate([seg[:, 0], seg[:, 2], cir[:, 0] - cir[:, 2], cir[:, 0] + cir[:, 2]])
    ys = np.concatenate([seg[:, 1], seg[:, 3], cir[:, 1] - cir[:, 2], cir[:, 1] + cir[:, 2]])
    x0, y0 = float(xs.min()) - margin, float(ys.min()) - margin
    width = max(1, math.ceil((float(xs.max()) + margin - x0) / resolution))
    height = max(1, math.ceil((float(ys.max()) + margin - y0) / resolution))
    return GridSpec(resolution, x0, y0, width, height)


# -- the true walls ---------------------------------------------------------------------------

def truth_occupancy(world: World, resolution: float, origin_x: float, origin_y: float,
                    width: int, height: int) -> np.ndarray:
    """The cells the world's walls and circle outlines pass through (``(height, width)``).

    Exact: every wall and circle outline is cut where it crosses a grid line, and the cell
    holding each piece's midpoint (and each end point) is marked, so a wall that only clips
    a cell's corner marks it too. Circles are outlines: their inside is not marked (a lidar
    never sees it).
    """
    grid = GridSpec(resolution, origin_x, origin_y, width, height)
    xs: list[np.ndarray] = [np.empty(0)]
    ys: list[np.ndarray] = [np.empty(0)]
    for x1, y1, x2, y2 in world.segment_array:
        u = _segment_cuts(grid, float(x1), float(y1), float(x2), float(y2))
        xs.append(x1 + u * (x2 - x1))
        ys.append(y1 + u * (y2 - y1))
    for cx, cy, r in world.circle_array:
        a = _circle_cuts(grid, float(cx), float(cy), float(r))
        xs.append(cx + r * np.cos(a))
        ys.append(cy + r * np.sin(a))
    return grid.mark(np.concatenate(xs), np.concatenate(ys))


def _line_crossings(origin: float, resolution: float, low: float, high: float) -> np.ndarray:
    """The grid lines ``origin + k * resolution`` between ``low`` and ``high``."""
    first = math.ceil((low - origin) / resolution)
    last = math.floor((high - origin) / resolution)
    return origin + np.arange(first, last + 1) * resolution


def _pieces(cuts: np.ndarray) -> np.ndarray:
    """Sorted cut parameters -> the cuts and the midpoint of every piece between them."""
    cuts = np.unique(cuts)
    return np.concatenate([cuts, (cuts[:-1] + cuts[1:]) / 2.0])


def _segment_cuts(grid: GridSpec, x1: float, y1: float, x2: float, y2: float) -> np.ndarray:
    cuts = [np.array([0.0, 1.0])]
    for a, b, origin in ((x1, x2, grid.origin_x), (y1, y2, grid.origin_y)):
        if a != b:
            lines = _line_crossings(origin, grid.resolution, min(a, b), max(a, b))
            cuts.append((lines - a) / (b - a))
    return _pieces(np.clip(np.concatenate(cuts), 0.0, 1.0))


def _circle_cuts(grid: GridSpec, cx: float, cy: float, r: float) -> np.ndarray:
    cuts = [np.array([0.0, 2 * math.pi])]
    for centre, origin, phase in ((cx, grid.origin_x, 0.0), (cy, grid.origin_y, math.pi / 2)):
        lines = _line_crossings(origin, grid.resolution, centre - r, centre + r)
        base = np.arccos(np.clip((lines - centre) / r, -1.0, 1.0))  # cos(a - phase) = offset
        cuts += [np.mod(phase + base, 2 * math.pi), np.mod(phase - base, 2 * math.pi)]
    return _pieces(np.concatenate(cuts))


def visible_walls(world: World, poses: Iterable[PoseLike], resolution: float,
                  origin_x: float, origin_y: float, width: int, height: int, *,
                  rays: int = 360, range_min: float = 0.1,
                  range_max: float = 10.0) -> np.ndarray:
    """The cells a noise-free lidar of ``rays`` rays hits from any of ``poses``.

    This is what a perfect mapper fed those revolutions could mark occupied: pass it as
    ``observed`` to :func:`map_precision_recall` to score recall over the walls that were
    seen, not over walls the robot never came near or that were always hidden.
    """
    grid = GridSpec(resolution, origin_x, origin_y, width, height)
    caster = RayCaster(world, ray_angles(rays), range_min, range_max)
    hits = np.zeros(grid.shape, dtype=bool)
    for pose in poses:
        x, y, theta = _xyt(pose)
        ranges = caster.cast(x, y, theta)
        seen = np.isfinite(ranges)
        angles = theta + caster.angles[seen]
        hits |= grid.mark(x + ranges[seen] * np.cos(angles), y + ranges[seen] * np.sin(angles))
    return hits


# -- scoring a map ----------------------------------------------------------------------------

def dilate(cells: np.ndarray, radius: int) -> np.ndarray:
    """Every cell within ``radius`` cells (Chebyshev distance: the square around) of a set one."""
    out = np.asarray(cells, dtype=bool).copy()
    for axis in (0, 1):
        spread = out.copy()
        for shift in range(1, radius + 1):
            spread[_slice(axis, shift, None)] |= out[_slice(axis, None, -shift)]
            spread[_slice(axis, None, -shift)] |= out[_slice(axis, shift, None)]
        out = spread
    return out


def _slice(axis: int, start: int | None, stop: int | None) -> tuple[slice, slice]:
    part = slice(start, stop)
    return (part, slice(None)) if axis == 0 else (slice(None), part)


def map_precision_recall(estimated_occupied: np.ndarray, truth: np.ndarray,
                         tolerance_cells: int = 1, *,
                         observed: np.ndarray | None = None) -> tuple[float, float]:
    """Precision and recall of a map's occupied cells against the true wall cells.

    Precision: the fraction of estimated occupied cells within ``tolerance_cells`` (the
    square around a cell) of a true wall cell. Recall: the fraction of true wall cells within
    ``tolerance_cells`` of an estimated occupied cell, over **all** true wall cells, or, with
    ``observed`` (e.g. :func:`visible_walls`), over the true wall cells within
    ``tolerance_cells`` of an observed cell only: walls never seen do not count against the
    map. The arrays must share one grid. A score with nothing to score (no estimated cell for
    precision, no true cell for recall) is 0.0.
    """
    estimated = np.asarray(estimated_occupied, dtype=bool)
    walls = np.asarray(truth, dtype=bool)
    _same_shape(estimated, walls, observed)
    if tolerance_cells < 0:
        raise ValueError(f"tolerance_cells must be >= 0, got {tolerance_cells}")
    scored = walls if observed is None else walls & dilate(observed, tolerance_cells)
    precision = _share(estimated, dilate(walls, tolerance_cells))
    recall = _share(scored, dilate(estimated, tolerance_cells))
    return precision, recall


def _same_shape(estimated: np.ndarray, truth: np.ndarray, observed: np.ndarray | None) -> None:
    shapes = {estimated.shape, truth.shape} | ({np.shape(observed)} if observed is not None
                                               else set())
    if len(shapes) != 1 or estimated.ndim != 2:
        raise ValueError(f"the grids must be 2-D and of one shape, got {sorted(shapes)}")


def _share(cells: np.ndarray, near: np.ndarray) -> float:
    total = int(cells.sum())
    return int((cells & near).sum()) / total if total else 0.0


# -- pose errors ------------------------------------------------------------------------------

class PoseErrors:
    """Accumulates position (m) and heading (reported in degrees) errors of pose estimates
    against the truth. Every figure is 0.0 before the first :meth:`add` (see :attr:`count`)."""

    def __init__(self) -> None:
        self.count = 0
        self.max_m = 0.0
        self._sum_sq_m = 0.0
        self._sum_sq_rad = 0.0
        self._max_rad = 0.0

    def add(self, estimate: PoseLike, truth: PoseLike) -> None:
        """One estimate against the true pose: ``Pose`` or ``(x, y, theta)``."""
        ex, ey, et = _xyt(estimate)
        tx, ty, tt = _xyt(truth)
        distance = math.hypot(ex - tx, ey - ty)
        heading = abs(math.atan2(math.sin(et - tt), math.cos(et - tt)))
        self.count += 1
        self._sum_sq_m += distance * distance
        self._sum_sq_rad += heading * heading
        self.max_m = max(self.max_m, distance)
        self._max_rad = max(self._max_rad, heading)

    @property
    def rms_m(self) -> float:
        return math.sqrt(self._sum_sq_m / self.count) if self.count else 0.0

    @property
    def rms_deg(self) -> float:
        return math.degrees(math.sqrt(self._sum_sq_rad / self.count)) if self.count else 0.0

    @property
    def max_deg(self) -> float:
        return math.degrees(self._max_rad)


def _xyt(pose: PoseLike) -> tuple[float, float, float]:
    if isinstance(pose, Pose):
        return pose.x, pose.y, pose.theta
    x, y, theta = pose
    return float(x), float(y), float(theta)


# -- where the robot can go -------------------------------------------------------------------

def clearances(world: World, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest wall or circle surface (shape of ``xs``)."""
    px, py = np.ravel(np.asarray(xs, dtype=float)), np.ravel(np.asarray(ys, dtype=float))
    out = np.empty(px.size)
    for start in range(0, px.size, CLEARANCE_BLOCK):
        part = slice(start, start + CLEARANCE_BLOCK)
        out[part] = _block_clearance(world, px[part], py[part])
    return out.reshape(np.shape(xs))


def _block_clearance(world: World, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    best = np.full(px.size, np.inf)
    seg, cir = world.segment_array, world.circle_array
    if len(seg):
        ax, ay = seg[:, 0][:, None], seg[:, 1][:, None]
        ex, ey = (seg[:, 2] - seg[:, 0])[:, None], (seg[:, 3] - seg[:, 1])[:, None]
        u = np.clip(((px - ax) * ex + (py - ay) * ey) / (ex * ex + ey * ey), 0.0, 1.0)
        best = np.minimum(best, np.hypot(ax + u * ex - px, ay + u * ey - py).min(axis=0))
    if len(cir):
        gaps = np.hypot(cir[:, 0][:, None] - px, cir[:, 1][:, None] - py) - cir[:, 2][:, None]
        best = np.minimum(best, gaps.min(axis=0))
    return best


def free_cells(world: World, grid: GridSpec, footprint_radius: float) -> np.ndarray:
    """Cells whose centre the robot's round footprint fits on (clearance > the radius)."""
    xs, ys = grid.centres()
    return np.asarray(clearances(world, xs, ys) > footprint_radius)


def reachable_free_cells(world: World, resolution: float, footprint_radius: float, *,
                         grid: GridSpec | None = None) -> np.ndarray:
    """The free cells (:func:`free_cells`) connected to the start pose's cell through free
    cells (4-neighbours), on ``grid`` (default :func:`world_grid` of the world at
    ``resolution``). Empty when the start cell is not free."""
    grid = grid or world_grid(world, resolution)
    free = free_cells(world, grid, footprint_radius)
    row, col = grid.cell_of(world.start.x, world.start.y)
    reached = np.zeros(grid.shape, dtype=bool)
    if 0 <= row < grid.height and 0 <= col < grid.width and free[row, col]:
        reached[row, col] = True
        return flood(reached, free)
    return reached


def flood(seed: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """Grow ``seed`` through 4-neighbours inside ``allowed`` until it stops growing."""
    reached = seed & allowed
    while True:
        grown = reached.copy()
        grown[1:, :] |= reached[:-1, :]
        grown[:-1, :] |= reached[1:, :]
        grown[:, 1:] |= reached[:, :-1]
        grown[:, :-1] |= reached[:, 1:]
        grown &= allowed
        if np.array_equal(grown, reached):
            return reached
        reached = grown
