# Grid planning: Dijkstra on a pooled cost grid (scipy), guided by a coarser search first,
# then string-pulling on the fine grid.
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from nav.costmap import GridArea

#: a path as grid cells (row, column), start first
Cells = list[tuple[int, int]]
#: how far (cells) the planner looks for a free cell when the start is in a lethal one
ESCAPE_CELLS = 6
#: the guided search (:func:`guided_path`): grids of at least this many blocks are searched
#: first on blocks of 2 x 2 blocks, then within GUIDE_MARGIN of those of that way; the way
#: found is kept when it costs at most GUIDE_SLACK times (plus GUIDE_EXTRA blocks) what the
#: first search found, else the whole grid is searched
GUIDE_MIN_BLOCKS = 4096
GUIDE_MARGIN = 3
GUIDE_SLACK, GUIDE_EXTRA = 1.1, 8.0
#: the straightened path is searched again within this many cells of the cheapest one (see
#: :func:`tightened`)
TIGHTEN_CELLS = 3
#: a plan on blocks is checked against the way over the fine cells pooled by twice the block,
#: each as cheap as its cheapest (every lane between cells is still there); when the blocks'
#: path is longer than LANE_SLACK times that way plus LANE_EXTRA cells, the blocks may have
#: closed a narrow lane, and blocks of half the size are searched too (see :func:`plan`)
LANE_SLACK, LANE_EXTRA = 1.1, 10
#: the 8 neighbours: row step, column step (in the order of their cells' indices, which is
#: the order scipy's search meets them in: equally cheap paths are told apart the same way)
NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


@dataclass(frozen=True)
class Plan:
    """A path in the grid's frame ((N, 2) metres, start to goal) and what it cost; ``reason``
    says why there is none when ``points`` is empty."""

    points: np.ndarray
    cost: float
    reason: str = ""
    #: no recovery can help (the goal itself is in an obstacle, or off the map)
    final: bool = False

    @property
    def found(self) -> bool:
        return len(self.points) > 0


def no_plan(reason: str, final: bool = False) -> Plan:
    return Plan(np.zeros((0, 2)), math.inf, reason, final)


def plan(costs: np.ndarray, area: GridArea, start: tuple[float, float],
         goal: tuple[float, float], pool: int = 2, line_cost: float = 0.0) -> Plan:
    """The cheapest path from ``start`` to ``goal`` over ``costs`` (per-metre cost per cell,
    ``inf`` lethal): searched on blocks of ``pool`` x ``pool`` cells (each as dear as its
    dearest cell), then shortened on the fine cells where a straight line crosses no cell
    dearer than the dearest it replaces or than ``line_cost`` (see :func:`shortcut`)."""
    s, g = area.cell(*start), area.cell(*goal)
    if not area.inside(*g):
        return no_plan("the goal is outside the map", final=True)
    if not area.inside(*s):
        return no_plan("the robot is outside the map")
    if not math.isfinite(float(costs[g])):
        return no_plan("the goal is inside an obstacle or too close to one for the footprint",
                       final=True)
    free_start = _escape(costs, s)
    if free_start is None:
        return no_plan("the robot is boxed in by obstacles")
    found = _plan_on_blocks(costs, area.resolution, free_start, g, pool, line_cost)
    if found is None:
        return no_plan("no path to the goal: every way is blocked by known obstacles")
    if pool > 1 and _lane_closed(costs, free_start, g, pool, _cells_length(found[0])):
        fine = _plan_on_blocks(costs, area.resolution, free_start, g, pool // 2, line_cost)
        if fine is not None and _cells_length(fine[0]) < _cells_length(found[0]):
            found = fine
    cells, cost = found
    points = np.array([area.centre(r, c) for r, c in cells], dtype=float)
    points[0], points[-1] = start, goal
    return Plan(points, cost)


def _plan_on_blocks(costs: np.ndarray, resolution: float, s: tuple[int, int],
                    g: tuple[int, int], pool: int, line_cost: float) -> tuple[Cells, float] | None:
    """The straightened path's cells over ``pool`` x ``pool`` blocks and its cost in metres;
    None when there is none."""
    coarse = pooled(costs, pool)
    cs, cg = (s[0] // pool, s[1] // pool), (g[0] // pool, g[1] // pool)
    coarse[cs], coarse[cg] = max(costs[s], 1.0), max(costs[g], 1.0)
    blocks, cost = guided_path(coarse, cs, cg)
    if not blocks:
        return None
    cells = [s] + [_block_centre(b, pool, costs.shape) for b in blocks[1:-1]] + [g]
    pulled = shortcut(costs, cells, line_cost)
    tight = tightened(costs, cells, line_cost)
    if tight is not None:
        tight = shortcut(costs, tight, line_cost)
        if _cells_length(tight) < _cells_length(pulled):
            pulled = tight
    return pulled, cost * pool * resolution


def _lane_closed(costs: np.ndarray, s: tuple[int, int], g: tuple[int, int], pool: int,
                 length: float) -> bool:
    """Whether a path of ``length`` cells over blocks of ``pool`` cells is clearly longer
    than the cheapest way over the fine cells pooled by ``2 * pool``, each as cheap as its
    cheapest: a lane narrower than a block that the blocks closed may be the shorter way."""
    k = 2 * pool
    way, _ = cheapest_path(_min_pooled_by(costs, k), (s[0] // k, s[1] // k),
                           (g[0] // k, g[1] // k))
    return bool(way) and length > LANE_SLACK * k * _cells_length(way) + LANE_EXTRA


def pooled(costs: np.ndarray, pool: int) -> np.ndarray:
    """Blocks of ``pool`` x ``pool`` cells, each as dear as its dearest (edges padded)."""
    if pool == 1:
        return costs.copy()
    h, w = costs.shape
    padded = np.full((-(-h // pool) * pool, -(-w // pool) * pool), np.inf, dtype=costs.dtype)
    padded[:h, :w] = costs
    out = padded[::pool, ::pool].copy()
    for dr in range(pool):
        for dc in range(pool):
            np.maximum(out, padded[dr::pool, dc::pool], out=out)
    return out


def _block_centre(block: tuple[int, int], pool: int, shape: tuple[int, ...]) -> tuple[int, int]:
    return (min(block[0] * pool + pool // 2, shape[0] - 1),
            min(block[1] * pool + pool // 2, shape[1] - 1))


@lru_cache(maxsize=4)
def _structure(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """The 8-connected grid's edges in CSR form, every cell with all 8 neighbours in the order
    of NEIGHBOURS (one past the edge of the grid: the cell itself, at an infinite weight):
    target of each edge, row pointers. The planner's grid keeps its shape: built once."""
    index = np.arange(h * w, dtype=np.int32).reshape(h, w)
    rows, cols = np.divmod(index, w)
    targets = np.empty((h, w, len(NEIGHBOURS)), dtype=np.int32)
    for k, (dr, dc) in enumerate(NEIGHBOURS):
        r, c = rows + dr, cols + dc
        inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        targets[:, :, k] = np.where(inside, r * w + c, index)
    pointers = np.arange(0, h * w * len(NEIGHBOURS) + 1, len(NEIGHBOURS), dtype=np.int32)
    targets.setflags(write=False)
    pointers.setflags(write=False)
    return targets.reshape(-1), pointers


#: half the length of the step to each neighbour
_HALF_STEPS = np.array([0.5 * math.hypot(dr, dc) for dr, dc in NEIGHBOURS])


def block_graph(costs: np.ndarray) -> Any:
    """The 8-connected graph of the cells of ``costs`` for scipy's csgraph: a step costs its
    length times the mean cost of its two cells (``inf``: a step never taken)."""
    from scipy.sparse import csr_matrix  # here, not at import: the daemon starts without scipy

    h, w = costs.shape
    targets, pointers = _structure(h, w)
    padded = np.full((h + 2, w + 2), np.inf)
    padded[1:-1, 1:-1] = costs
    weights = np.empty((h, w, len(NEIGHBOURS)))
    for k, (dr, dc) in enumerate(NEIGHBOURS):
        np.add(padded[1:-1, 1:-1], padded[1 + dr:1 + dr + h, 1 + dc:1 + dc + w],
               out=weights[:, :, k])
    weights *= _HALF_STEPS
    return csr_matrix((weights.reshape(-1), targets, pointers), shape=(h * w, h * w))


def cheapest_path(costs: np.ndarray, start: tuple[int, int],
                  goal: tuple[int, int]) -> tuple[list[tuple[int, int]], float]:
    """Cells of the cheapest 8-connected path (start first) and its cost in cells; a step
    costs its length times the mean cost of its two cells. Empty when none exists."""
    from scipy.sparse.csgraph import dijkstra

    w = costs.shape[1]
    s, g = start[0] * w + start[1], goal[0] * w + goal[1]
    distances, predecessors = dijkstra(block_graph(costs), indices=s,
                                       return_predecessors=True)
    if not math.isfinite(float(distances[g])):
        return [], math.inf
    path = [g]
    while path[-1] != s:
        path.append(int(predecessors[path[-1]]))
    path.reverse()
    return [divmod(cell, w) for cell in path], float(distances[g])


def guided_path(costs: np.ndarray, start: tuple[int, int],
                goal: tuple[int, int]) -> tuple[list[tuple[int, int]], float]:
    """What :func:`cheapest_path` finds, searching less of a large grid: first the cheapest
    way over blocks of 2 x 2 cells, each as cheap as its cheapest (every way between the
    cells is still there, so none found means none exists), then the cheapest path over the
    cells within GUIDE_MARGIN blocks of that way. When that costs clearly more than the first
    search (which is about a lower bound), or finds nothing, the whole grid is searched."""
    h, w = costs.shape
    if h * w < GUIDE_MIN_BLOCKS:
        return cheapest_path(costs, start, goal)
    from scipy import ndimage

    coarse = _min_pooled(costs)
    way, bound = cheapest_path(coarse, (start[0] // 2, start[1] // 2),
                               (goal[0] // 2, goal[1] // 2))
    if not way:
        return [], math.inf
    near = np.zeros(coarse.shape, dtype=bool)
    along = np.array(way)
    near[along[:, 0], along[:, 1]] = True
    near = ndimage.binary_dilation(near, np.ones((3, 3), dtype=bool), GUIDE_MARGIN)
    near = np.repeat(np.repeat(near, 2, axis=0), 2, axis=1)[:h, :w]
    path, cost = cheapest_path(np.where(near, costs, np.inf), start, goal)
    if path and cost <= GUIDE_SLACK * 2.0 * bound + GUIDE_EXTRA:
        return path, cost
    return cheapest_path(costs, start, goal)


def _min_pooled(costs: np.ndarray) -> np.ndarray:
    """Blocks of 2 x 2 cells, each as cheap as its cheapest (edges padded)."""
    return _min_pooled_by(costs, 2)


def _min_pooled_by(costs: np.ndarray, k: int) -> np.ndarray:
    """Blocks of ``k`` x ``k`` cells, each as cheap as its cheapest (edges padded)."""
    h, w = costs.shape
    padded = np.full((-(-h // k) * k, -(-w // k) * k), np.inf, dtype=costs.dtype)
    padded[:h, :w] = costs
    out = padded[::k, ::k].copy()
    for dr in range(k):
        for dc in range(k):
            np.minimum(out, padded[dr::k, dc::k], out=out)
    return out


def _escape(costs: np.ndarray, cell: tuple[int, int]) -> tuple[int, int] | None:
    """``cell`` if it is not lethal, else the nearest cell that is (within ESCAPE_CELLS)."""
    if math.isfinite(float(costs[cell])):
        return cell
    r0, c0 = cell
    h, w = costs.shape
    rows = slice(max(0, r0 - ESCAPE_CELLS), min(h, r0 + ESCAPE_CELLS + 1))
    cols = slice(max(0, c0 - ESCAPE_CELLS), min(w, c0 + ESCAPE_CELLS + 1))
    window = np.isfinite(costs[rows, cols])
    if not window.any():
        return None
    rr, cc = np.nonzero(window)
    rr, cc = rr + rows.start, cc + cols.start
    best = int(np.argmin(np.hypot(rr - r0, cc - c0)))
    return int(rr[best]), int(cc[best])


def shortcut(costs: np.ndarray, cells: list[tuple[int, int]],
             line_cost: float = 0.0) -> list[tuple[int, int]]:
    """Drop the cells a straight line can skip: a line from one kept cell to a later one
    replaces the cells between when no cell it crosses costs more than the dearest of them
    or than ``line_cost`` (the straight run never goes nearer obstacles than the grid path
    did, or than the distance where cells cost ``line_cost``: the band's cost keeps the grid
    path in the middle of the free space, the lines need not). The farthest such cell is
    searched by doubling then halving the jump: a few line checks per kept cell."""
    if len(cells) < 3:
        return cells
    index = np.array(cells)
    along = np.maximum(costs[index[:, 0], index[:, 1]].astype(np.float64), line_cost)
    kept = [cells[0]]
    i, last = 0, len(cells) - 1
    while i < last:
        good, bad, jump = i + 1, last + 1, 1
        while good < last:
            k = min(i + 2 * jump, last)
            if not _straight(costs, cells, along, i, k):
                bad = k
                break
            good, jump = k, 2 * jump
        while bad - good > 1:
            middle = (good + bad) // 2
            if _straight(costs, cells, along, i, middle):
                good = middle
            else:
                bad = middle
        kept.append(cells[good])
        i = good
    return kept


def _straight(costs: np.ndarray, cells: list[tuple[int, int]], along: np.ndarray, i: int,
              k: int) -> bool:
    """Whether the line from cell ``i`` to cell ``k`` of the path may replace the cells
    between."""
    return _line_cost(costs, cells[i], cells[k]) <= float(along[i:k + 1].max()) + 1e-6


def _line_cost(costs: np.ndarray, a: tuple[int, int], b: tuple[int, int]) -> float:
    """The dearest cell a straight line from the centre of ``a`` to that of ``b`` crosses
    (sampled twice per cell of its longer side, as ``np.linspace`` would, with fewer calls)."""
    global _ramp
    dr, dc = b[0] - a[0], b[1] - a[1]
    steps = 2 * max(abs(dr), abs(dc))
    if steps == 0:
        return float(costs[a])
    if len(_ramp) <= steps:
        _ramp = np.arange(2 * steps + 1, dtype=np.float64)
    ramp = _ramp[:steps + 1]
    rows = np.rint(ramp * (dr / steps) + a[0]).astype(np.intp)
    cols = np.rint(ramp * (dc / steps) + a[1]).astype(np.intp)
    return float(costs[rows, cols].max())


#: 0, 1, 2, ... for the line samples (grown when a longer line comes)
_ramp = np.arange(1025, dtype=np.float64)


def _cells_length(cells: list[tuple[int, int]]) -> float:
    steps = np.diff(np.array(cells, dtype=float), axis=0)
    return float(np.hypot(steps[:, 0], steps[:, 1]).sum())


def _rasterised(cells: list[tuple[int, int]]) -> np.ndarray:
    """The cells of the polyline through ``cells`` ((K, 2) rows and columns, 8-connected)."""
    corners = np.array(cells, dtype=np.float64)
    steps = np.diff(corners, axis=0)
    counts = np.abs(steps).max(axis=1).astype(np.intp)
    segment = np.repeat(np.arange(len(counts)), counts)
    k = np.arange(len(segment)) - np.repeat(np.cumsum(counts) - counts, counts) + 1
    along = corners[segment] + (k / counts[segment])[:, None] * steps[segment]
    return np.concatenate((corners[:1], np.rint(along))).astype(np.intp)


def tightened(costs: np.ndarray, cells: list[tuple[int, int]],
              line_cost: float = 0.0) -> list[tuple[int, int]] | None:
    """The shortest 8-connected path from the first to the last of ``cells`` (the cheapest
    path) through the cells within TIGHTEN_CELLS of it that cost no more than the dearest
    cell of it within TIGHTEN_CELLS, or than ``line_cost``: as near obstacles as the cheapest
    path goes there (or the line margin), never nearer. The band's cost makes the cheapest
    path cross it squarely (through a door approached from beside its wall: round a stair of
    corners); straightening picks corners on the path only, so the stair stays, while the
    shortest way in the same clearance cuts it. None when no way is found."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    h, w = costs.shape
    along = _rasterised(cells)
    reach = np.arange(-TIGHTEN_CELLS, TIGHTEN_CELLS + 1)
    offsets = np.stack(np.meshgrid(reach, reach, indexing="ij"), axis=-1).reshape(-1, 2)
    near = (along[:, None, :] + offsets[None, :, :]).reshape(-1, 2)
    inside = (near[:, 0] >= 0) & (near[:, 0] < h) & (near[:, 1] >= 0) & (near[:, 1] < w)
    limit = np.full(h * w, -np.inf)  # per cell: the dearest path cell within reach
    np.maximum.at(limit, near[inside, 0] * w + near[inside, 1],
                  np.repeat(costs[along[:, 0], along[:, 1]].astype(np.float64),
                            len(offsets))[inside])
    flat_costs = costs.reshape(-1)
    allowed = flat_costs <= np.maximum(limit, line_cost) + 1e-6  # inf never, -inf: not near
    ends = along[[0, -1], 0] * w + along[[0, -1], 1]
    allowed[ends] = True
    flat = np.flatnonzero(allowed & np.isfinite(limit))
    index = np.full(h * w, -1, dtype=np.intp)
    index[flat] = np.arange(len(flat))
    rows, cols = np.divmod(flat, w)
    sources, targets, weights = [], [], []
    for dr, dc in NEIGHBOURS:
        r, c = rows + dr, cols + dc
        ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        target = np.where(ok, index[np.where(ok, r * w + c, 0)], -1)
        ok = target >= 0
        sources.append(np.nonzero(ok)[0])
        targets.append(target[ok])
        weights.append(np.full(int(ok.sum()), math.hypot(dr, dc)))
    graph = csr_matrix((np.concatenate(weights), (np.concatenate(sources),
                                                  np.concatenate(targets))),
                       shape=(len(flat), len(flat)))
    start, goal = int(index[ends[0]]), int(index[ends[1]])
    distances, predecessors = dijkstra(graph, indices=start, return_predecessors=True)
    if not math.isfinite(float(distances[goal])):
        return None
    path = [goal]
    while path[-1] != start:
        path.append(int(predecessors[path[-1]]))
    path.reverse()
    return [(int(rows[i]), int(cols[i])) for i in path]
