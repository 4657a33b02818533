# Grid planning: Dijkstra on a pooled cost grid (scipy), then string-pulling on the fine grid.
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from nav.costmap import GridArea

#: how far (cells) the planner looks for a free cell when the start is in a lethal one
ESCAPE_CELLS = 6
#: the 8 neighbours: row step, column step
NEIGHBOURS = ((0, 1), (1, 0), (1, 1), (1, -1), (0, -1), (-1, 0), (-1, -1), (-1, 1))


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
         goal: tuple[float, float], pool: int = 2) -> Plan:
    """The cheapest path from ``start`` to ``goal`` over ``costs`` (per-metre cost per cell,
    ``inf`` lethal): searched on blocks of ``pool`` x ``pool`` cells (each as dear as its
    dearest cell), then shortened on the fine cells where a straight line costs no more."""
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
    s = free_start
    coarse = pooled(costs, pool)
    cs, cg = (s[0] // pool, s[1] // pool), (g[0] // pool, g[1] // pool)
    coarse[cs], coarse[cg] = max(costs[s], 1.0), max(costs[g], 1.0)
    blocks, cost = cheapest_path(coarse, cs, cg)
    if not blocks:
        return no_plan("no path to the goal: every way is blocked by known obstacles")
    cells = [s] + [_block_centre(b, pool, costs.shape) for b in blocks[1:-1]] + [g]
    cells = shortcut(costs, cells)
    points = np.array([area.centre(r, c) for r, c in cells], dtype=float)
    points[0], points[-1] = start, goal
    return Plan(points, cost * pool * area.resolution)


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


def grid_graph(h: int, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The 8-connected grid's edges in CSR order: source, target, length, row pointers."""
    index = np.arange(h * w).reshape(h, w)
    sources, targets, lengths = [], [], []
    for dr, dc in NEIGHBOURS:
        a = index[max(0, -dr):h - max(0, dr), max(0, -dc):w - max(0, dc)].ravel()
        b = index[max(0, dr):h + min(0, dr), max(0, dc):w + min(0, dc)].ravel()
        sources.append(a)
        targets.append(b)
        lengths.append(np.full(a.size, math.hypot(dr, dc)))
    source, target = np.concatenate(sources), np.concatenate(targets)
    order = np.lexsort((target, source))
    source, target = source[order], target[order]
    length = np.concatenate(lengths)[order]
    return source, target, length, np.searchsorted(source, np.arange(h * w + 1))


#: the planner's grid keeps its shape: its graph is built once
_graph = lru_cache(maxsize=2)(grid_graph)


def cheapest_path(costs: np.ndarray, start: tuple[int, int],
                  goal: tuple[int, int]) -> tuple[list[tuple[int, int]], float]:
    """Cells of the cheapest 8-connected path (start first) and its cost in cells; a step
    costs its length times the mean cost of its two cells. Empty when none exists."""
    from scipy.sparse import csr_matrix  # here, not at import: the daemon starts without scipy
    from scipy.sparse.csgraph import dijkstra

    h, w = costs.shape
    source, target, length, pointers = _graph(h, w)
    flat = costs.ravel().astype(np.float64)
    weights = length * 0.5 * (flat[source] + flat[target])  # inf: a step never taken
    graph = csr_matrix((weights, target, pointers), shape=(h * w, h * w))
    s, g = start[0] * w + start[1], goal[0] * w + goal[1]
    distances, predecessors = dijkstra(graph, indices=s, return_predecessors=True)
    if not math.isfinite(float(distances[g])):
        return [], math.inf
    path = [g]
    while path[-1] != s:
        path.append(int(predecessors[path[-1]]))
    path.reverse()
    return [divmod(cell, w) for cell in path], float(distances[g])


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


def shortcut(costs: np.ndarray, cells: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Drop the cells a straight line can skip: a line from one kept cell to a later one
    replaces the cells between when no cell it crosses costs more than the dearest of them
    (the straight run never goes nearer obstacles than the grid path did). The farthest such
    cell is searched by doubling then halving the jump: a few line checks per kept cell."""
    if len(cells) < 3:
        return cells
    along = np.array([float(costs[rc]) for rc in cells])
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
    """The dearest cell a straight line from the centre of ``a`` to that of ``b`` crosses."""
    n = 2 * max(abs(b[0] - a[0]), abs(b[1] - a[1])) + 1
    rows = np.rint(np.linspace(a[0], b[0], n)).astype(np.int64)
    cols = np.rint(np.linspace(a[1], b[1], n)).astype(np.int64)
    return float(costs[rows, cols].max())
