# Coverage of the reachable free area: which cells of the world the robot's centre visited.
from __future__ import annotations

import math

import numpy as np

from sim.mapping_truth import dilate, reachable_free_cells, world_grid
from sim.world import World

#: Cell size (m) of the flood fill that decides which cell centres the robot can reach.
REACH_RESOLUTION = 0.05


class Coverage:
    """A grid of ``cell`` m squares over the world's bounding box. A cell is *free* when the
    robot could stand at its centre (clearance above ``radius``) and get there from the start
    (a closed room, a shelf's inside or the block a corridor loops round is not free);
    coverage is the share of free cells whose area the robot's centre has entered."""

    def __init__(self, world: World, radius: float, cell: float = 0.5) -> None:
        points = np.concatenate([world.segment_array[:, 0:2], world.segment_array[:, 2:4],
                                 world.circle_array[:, 0:2]]) if len(world.segments) else \
            world.circle_array[:, 0:2]
        self.cell = cell
        self.x0, self.y0 = float(points[:, 0].min()), float(points[:, 1].min())
        self.nx = max(1, math.ceil((float(points[:, 0].max()) - self.x0) / cell))
        self.ny = max(1, math.ceil((float(points[:, 1].max()) - self.y0) / cell))
        centres = [(self.x0 + (i + 0.5) * cell, self.y0 + (j + 0.5) * cell)
                   for j in range(self.ny) for i in range(self.nx)]
        self.free = np.array([world.clearance(x, y) > radius for x, y in centres],
                             dtype=bool) & _reachable(world, radius, centres)
        self.visited = np.zeros(self.nx * self.ny, dtype=bool)
        self._last = -1

    def visit(self, x: float, y: float) -> None:
        i, j = int((x - self.x0) // self.cell), int((y - self.y0) // self.cell)
        if 0 <= i < self.nx and 0 <= j < self.ny:
            index = j * self.nx + i
            if index != self._last:
                self.visited[index] = True
                self._last = index

    @property
    def free_cells(self) -> int:
        return int(self.free.sum())

    @property
    def visited_free(self) -> int:
        return int((self.visited & self.free).sum())

    @property
    def fraction(self) -> float:
        return self.visited_free / self.free_cells if self.free_cells else 0.0


def _reachable(world: World, radius: float,
               centres: list[tuple[float, float]]) -> np.ndarray:
    """Whether each point lies in or next to a cell the robot can reach from the start (flood
    fill; "next to" so that a point the footprint just fits on is not lost to the grid)."""
    grid = world_grid(world, REACH_RESOLUTION)
    reached = dilate(reachable_free_cells(world, REACH_RESOLUTION, radius, grid=grid), 1)
    out = np.zeros(len(centres), dtype=bool)
    for index, (x, y) in enumerate(centres):
        row, col = grid.cell_of(x, y)
        out[index] = 0 <= row < grid.height and 0 <= col < grid.width and reached[row, col]
    return out
