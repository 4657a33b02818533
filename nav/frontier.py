# Frontier exploration: where known free space meets the unknown, clustered, reached, ranked.
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from nav.costmap import GridArea
from nav.planner import block_graph, pooled

#: unknown pockets of fewer cells than this, enclosed by known cells, count as known: the gaps
#: between a revolution's rays far from the robot, not places to go and look at
HOLE_CELLS = 10
#: the search covers the box of the known cells grown by this many cells (and the robot)
MARGIN_CELLS = 10
#: the 8 neighbours and the cell itself, for clustering
EIGHT = np.ones((3, 3), dtype=bool)


@dataclass(frozen=True)
class Frontier:
    """A cluster of frontier cells: the point to drive to (``x``, ``y``: the reachable cell of
    the cluster nearest its centroid), its size (cells x resolution, m), what the cheapest
    way there costs (``cost_m``: a free metre costs 1, the costmap's costs per metre) and the
    centres of its cells ((N, 2), m)."""

    x: float
    y: float
    size_m: float
    cost_m: float
    cells: np.ndarray

    def score(self, size_weight: float) -> float:
        """Lower is better: the way there, less ``size_weight`` per metre of frontier."""
        return self.cost_m - size_weight * self.size_m

    def near(self, x: float, y: float, radius: float) -> bool:
        """Whether any of its cells lies within ``radius`` of (x, y)."""
        gaps = np.hypot(self.cells[:, 0] - x, self.cells[:, 1] - y)
        return bool((gaps <= radius).any())


def frontier_cells(free: np.ndarray, unknown: np.ndarray) -> np.ndarray:
    """Known free cells with an unknown 4-neighbour."""
    beside = np.zeros_like(unknown)
    beside[1:, :] |= unknown[:-1, :]
    beside[:-1, :] |= unknown[1:, :]
    beside[:, 1:] |= unknown[:, :-1]
    beside[:, :-1] |= unknown[:, 1:]
    return free & beside


def without_small_holes(unknown: np.ndarray, max_cells: int = HOLE_CELLS) -> np.ndarray:
    """``unknown`` less its 4-connected pockets of fewer than ``max_cells`` cells that do not
    touch the grid's edge."""
    from scipy import ndimage  # here, not at import: the daemon starts without scipy

    labels, count = ndimage.label(unknown)
    if count == 0:
        return unknown.copy()
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    small = sizes < max_cells
    edge = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    small[edge] = False
    small[0] = False
    return unknown & ~small[labels]


def known_free_m2(seen: np.ndarray, obstacles: np.ndarray, resolution: float) -> float:
    """The area seen and free (m²)."""
    return float(np.count_nonzero(seen & ~obstacles)) * resolution * resolution


def find_frontiers(costs: np.ndarray, seen: np.ndarray, obstacles: np.ndarray,
                   area: GridArea, start: tuple[float, float], *, min_cells: int = 3,
                   block: int = 2) -> list[Frontier]:
    """The frontiers the robot at ``start`` can reach, as the planner would (``costs`` per
    metre, ``inf`` lethal; searched on the planner's blocks of ``block`` x ``block`` cells):
    clusters (8-connected) of at least ``min_cells`` frontier cells, each with a reachable
    cell that is not lethal. Unsorted; see :func:`choose`."""
    from scipy import ndimage  # here, not at import: the daemon starts without scipy

    box = _box(seen, area.cell(*start), block)
    if box is None:
        return []
    r0, r1, c0, c1 = box
    crop = (slice(r0, r1), slice(c0, c1))
    unknown = without_small_holes(~seen[crop])
    fringe = frontier_cells(seen[crop] & ~obstacles[crop], unknown)
    labels, count = ndimage.label(fringe, EIGHT)
    if count == 0:
        return []
    cost = costs[crop]
    reach = _block_costs(cost, area.cell(*start), (r0, c0), block) * block * area.resolution
    rows, cols = np.nonzero(labels)
    label = labels[rows, cols]
    order = np.argsort(label, kind="stable")
    rows, cols, label = rows[order], cols[order], label[order]
    way = reach[rows // block, cols // block]
    way[~np.isfinite(cost[rows, cols])] = np.inf
    xs = area.origin_x + (cols + c0 + 0.5) * area.resolution
    ys = area.origin_y + (rows + r0 + 0.5) * area.resolution
    bounds = np.searchsorted(label, np.arange(1, count + 2))
    found = []
    for k in range(count):
        part = slice(bounds[k], bounds[k + 1])
        size = part.stop - part.start
        ok = np.isfinite(way[part])
        if size < min_cells or not ok.any():
            continue
        px, py = xs[part], ys[part]
        gaps = np.hypot(px - px.mean(), py - py.mean())
        gaps[~ok] = np.inf
        i = int(np.argmin(gaps))
        found.append(Frontier(float(px[i]), float(py[i]), size * area.resolution,
                              float(way[part][i]), np.column_stack((px, py))))
    return found


def choose(frontiers: Sequence[Frontier], size_weight: float,
           blacklist: Sequence[tuple[float, float]] = (),
           radius: float = 0.5) -> Frontier | None:
    """The best frontier (lowest :meth:`Frontier.score`) with none of its cells within
    ``radius`` of a blacklisted point; None when there is none."""
    allowed = [f for f in frontiers if not any(f.near(x, y, radius) for x, y in blacklist)]
    return min(allowed, key=lambda f: f.score(size_weight), default=None)


def _box(seen: np.ndarray, start: tuple[int, int],
         block: int) -> tuple[int, int, int, int] | None:
    """Rows and columns (ends exclusive) of the known cells and the robot, grown by
    MARGIN_CELLS, starting on a block boundary of the planner's grid."""
    h, w = seen.shape
    rows, cols = np.nonzero(seen)
    if len(rows) == 0 or not (0 <= start[0] < h and 0 <= start[1] < w):
        return None
    r0 = max(0, min(int(rows.min()), start[0]) - MARGIN_CELLS) // block * block
    c0 = max(0, min(int(cols.min()), start[1]) - MARGIN_CELLS) // block * block
    r1 = min(h, max(int(rows.max()), start[0]) + MARGIN_CELLS + 1)
    c1 = min(w, max(int(cols.max()), start[1]) + MARGIN_CELLS + 1)
    return r0, r1, c0, c1


def _block_costs(costs: np.ndarray, start: tuple[int, int], corner: tuple[int, int],
                 block: int) -> np.ndarray:
    """The cost of the cheapest way from ``start`` (a cell of the whole grid) to each block
    of ``costs`` (a crop whose first cell is ``corner``), in blocks; a block is counted
    reachable when a neighbour is (the planner makes its goal's block passable)."""
    from scipy import ndimage
    from scipy.sparse.csgraph import dijkstra

    coarse = pooled(costs, block)
    h, w = coarse.shape
    s = ((start[0] - corner[0]) // block, (start[1] - corner[1]) // block)
    coarse[s] = max(float(coarse[s]), 1.0) if math.isfinite(float(coarse[s])) else 1.0
    distances = np.asarray(dijkstra(block_graph(coarse), indices=s[0] * w + s[1])).reshape(h, w)
    grown: np.ndarray = ndimage.minimum_filter(distances, size=3, mode="constant",
                                               cval=np.inf)
    return grown
