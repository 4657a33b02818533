# Coverage of the free area: which grid cells of the world the robot's centre has visited.
from __future__ import annotations

import math

import numpy as np

from sim.world import World


class Coverage:
    """A grid of ``cell`` m squares over the world's bounding box. A cell is *free* when the
    robot could stand at its centre (clearance above ``radius``); coverage is the share of
    free cells whose area the robot's centre has entered."""

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
                             dtype=bool)
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
