# The map as rigid submaps composed by pose: a correction moves submaps, it re-integrates nothing.
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from slam.grid import OBSERVED_EPSILON, OccupancyGrid
from slam.pose import Pose2, between, compose

#: a submap is re-placed once its pose moved this share of a cell (at its farthest cell)
MOVE_SHARE = 0.5


@dataclass
class Submap:
    """Consecutive key scans (``count`` of them from ``first``, the anchor) integrated in the
    submap's frame: the anchor's pose composed with ``offset``, chosen when the submap began
    so that its grid's cells then coincided with the map's (a correction moves them by the
    correction only); ``placed``: the frame's map pose at which the grid is in
    the composed sum (None: not)."""

    def frame(self, anchor: Pose2) -> Pose2:
        """The submap's frame for its anchor's map pose."""
        return compose(anchor, self.offset)

    first: int
    grid: OccupancyGrid
    offset: Pose2
    count: int = 0
    placed: Pose2 | None = None
    finished: bool = False

    @property
    def keys(self) -> range:
        return range(self.first, self.first + self.count)


class SubmapAtlas:
    """Key scans grouped ``keys_per_submap`` at a time into submaps; the map is the sum of
    the submaps' log-odds placed at their anchors' poses (each submap clamped by itself,
    the sum clamped when read). ``compose`` re-places only the submaps whose pose moved by
    more than half a cell since they were placed, and re-integrates a submap's own key
    scans only when the graph moved them relative to each other: its cost follows what a
    correction changed, not the length of the run."""

    def __init__(self, resolution: float, max_cells: int, keys_per_submap: int = 20) -> None:
        self.resolution = resolution
        self.max_cells = max_cells
        self.keys_per_submap = max(1, keys_per_submap)
        self.submaps: list[Submap] = []
        #: per key scan: its pose relative to its submap's anchor when integrated, the anchor
        self.relative: list[Pose2] = []
        self.first_of: list[int] = []
        self.offset_of: list[Pose2] = []
        self.total = OccupancyGrid(resolution, max_cells)  # unclamped sum of the submaps
        self.seen = np.zeros_like(self.total.log_odds, dtype=np.int32)  # submaps seeing a cell
        #: cell (0, 0) of the sum is this many cells right of and above where it began: cell
        #: centres are computed from integers (the same cells however often the sum grew)
        self._base = (self.total.origin_x, self.total.origin_y)
        self._shift = [0, 0]
        self.view = OccupancyGrid(resolution, max_cells)
        self._dirty: set[int] = set()
        self._changed = False
        #: what the last compose() did: re-placed and re-integrated submaps
        self.last_placed = 0
        self.last_rebuilt = 0

    # -- building ---------------------------------------------------------------------------

    def add_key(self, index: int, pose: Pose2, anchor: Pose2 | None, points: np.ndarray) -> None:
        """Key scan ``index`` at map pose ``pose``; ``anchor``: the map pose of the active
        submap's first key (None for a new submap's first key)."""
        active = self.submaps[-1] if self.submaps else None
        if active is None or active.finished or anchor is None:
            if active is not None:
                self._finish(active)
            res = self.resolution
            lattice = (round(pose[0] / res) * res, round(pose[1] / res) * res, 0.0)
            active = Submap(index, self._local_grid(), between(pose, lattice))
            self.submaps.append(active)
            anchor = pose
        if index != len(self.relative):
            raise ValueError(f"key scan {index} added after {len(self.relative)} of them")
        relative = between(active.frame(anchor), pose)
        if active.placed is not None:  # taken out as it is in the sum, before it changes
            self._unplace(active)
        active.grid.integrate(relative, points)
        active.count += 1
        self.relative.append(relative)
        self.first_of.append(active.first)
        self.offset_of.append(active.offset)
        if active.count >= self.keys_per_submap:
            self._finish(active)
        self._dirty.add(len(self.submaps) - 1)

    def anchor_key(self) -> int | None:
        """The first key of the submap the next key scan joins (None: it starts one)."""
        if not self.submaps or self.submaps[-1].finished:
            return None
        return self.submaps[-1].first

    def _local_grid(self) -> OccupancyGrid:
        return OccupancyGrid(self.resolution, self.max_cells)

    def _finish(self, submap: Submap) -> None:
        if not submap.finished:  # cropping keeps every observed value: the sum stays right
            submap.finished = True
            submap.grid = submap.grid.cropped()

    # -- composing --------------------------------------------------------------------------

    def compose(self, poses: np.ndarray, points_of: Callable[[int], np.ndarray],
                moved: bool = True) -> None:
        """Bring the sum up to date with the graph's ``poses`` (n, 3); ``moved``: the graph
        may have moved key scans since the last call (else only new key scans are placed)."""
        self.last_placed = self.last_rebuilt = 0
        for number in self._bent(poses) if moved else ():
            self._rebuild(self.submaps[number], poses, points_of)
            self._dirty.add(number)
            self.last_rebuilt += 1
        for number, submap in enumerate(self.submaps if moved else ()):
            if submap.placed is not None and number not in self._dirty and \
                    self._moved(submap, poses):
                self._dirty.add(number)
        for number in sorted(self._dirty):
            submap = self.submaps[number]
            self._place(submap, submap.frame(_pose(poses[submap.first])))
            self.last_placed += 1
        self._changed |= bool(self._dirty)
        self._dirty.clear()

    def _tolerance(self, submap: Submap) -> tuple[float, float]:
        """(m, rad) a submap may move before a cell of it would land elsewhere."""
        g = submap.grid
        corners = np.array([[g.origin_x, g.origin_y],
                            [g.origin_x + g.width * g.resolution,
                             g.origin_y + g.height * g.resolution]])
        reach = max(float(np.abs(corners).max()) * math.sqrt(2), self.resolution)
        step = MOVE_SHARE * self.resolution
        return step, step / reach

    def _moved(self, submap: Submap, poses: np.ndarray) -> bool:
        assert submap.placed is not None
        shift = between(submap.placed, submap.frame(_pose(poses[submap.first])))
        linear, angular = self._tolerance(submap)
        return math.hypot(shift[0], shift[1]) > linear or abs(shift[2]) > angular

    def _bent(self, poses: np.ndarray) -> list[int]:
        """The submaps whose key scans the graph moved relative to their anchor by more than
        half a cell since they were integrated (vectorised over every key scan)."""
        count = len(self.relative)
        if not count:
            return []
        frames = compose_poses(poses[np.asarray(self.first_of, dtype=np.int64)],
                               np.asarray(self.offset_of))
        now = relative_poses(frames, poses[:count])
        then = np.asarray(self.relative)
        linear = np.hypot(now[:, 0] - then[:, 0], now[:, 1] - then[:, 1])
        angular = np.abs(np.remainder(now[:, 2] - then[:, 2] + math.pi, math.tau) - math.pi)
        bent = []
        for number, submap in enumerate(self.submaps):
            keys = submap.keys
            lin, ang = self._tolerance(submap)
            if (linear[keys.start:keys.stop] > lin).any() or \
                    (angular[keys.start:keys.stop] > ang).any():
                bent.append(number)
        return bent

    def _rebuild(self, submap: Submap, poses: np.ndarray,
                 points_of: Callable[[int], np.ndarray]) -> None:
        """Re-integrate the submap's key scans at their poses relative to its anchor now."""
        keys = submap.keys
        frame = np.asarray(submap.frame(_pose(poses[submap.first])))
        now = relative_poses(np.repeat(frame[None, :], len(keys), axis=0),
                             poses[keys.start:keys.stop])
        if submap.placed is not None:  # taken out as it is in the sum, before it changes
            self._unplace(submap)
        grid = self._local_grid()
        for k, relative in zip(keys, now, strict=True):
            pose = (float(relative[0]), float(relative[1]), float(relative[2]))
            grid.integrate(pose, points_of(k))
            self.relative[k] = pose
        submap.grid = grid.cropped() if submap.finished else grid

    def _place(self, submap: Submap, anchor: Pose2) -> None:
        if submap.placed is not None:
            self._unplace(submap)
        self._cover(submap, anchor)
        self._add(submap, anchor, 1)
        submap.placed = anchor

    def _unplace(self, submap: Submap) -> None:
        assert submap.placed is not None
        self._add(submap, submap.placed, -1)
        submap.placed = None

    def _cover(self, submap: Submap, anchor: Pose2) -> None:
        """Grow the sum (and its counts) to cover the submap at ``anchor``."""
        old = (self.total.origin_x, self.total.origin_y, self.total.width, self.total.height)
        self.total.cover(self._corners(submap.grid, anchor))
        if old == (self.total.origin_x, self.total.origin_y, self.total.width,
                   self.total.height):
            return
        col = round((old[0] - self.total.origin_x) / self.resolution)
        row = round((old[1] - self.total.origin_y) / self.resolution)
        seen = np.zeros_like(self.total.log_odds, dtype=np.int32)
        seen[row:row + old[3], col:col + old[2]] = self.seen
        self.seen = seen
        self._shift[0] -= col
        self._shift[1] -= row

    @staticmethod
    def _corners(grid: OccupancyGrid, pose: Pose2) -> np.ndarray:
        x0, y0 = grid.origin_x, grid.origin_y
        x1, y1 = x0 + grid.width * grid.resolution, y0 + grid.height * grid.resolution
        local = np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]])
        c, s = math.cos(pose[2]), math.sin(pose[2])
        return np.column_stack([pose[0] + c * local[:, 0] - s * local[:, 1],
                                pose[1] + s * local[:, 0] + c * local[:, 1]])

    def _add(self, submap: Submap, pose: Pose2, sign: int) -> None:
        """Add (sign 1) or take away (-1) the submap's log-odds placed at ``pose``: each cell
        of the sum takes the submap cell under its centre (the same cells both ways)."""
        total, local = self.total, submap.grid
        res = self.resolution
        cells = total.cell_of(self._corners(local, pose))
        c0, r0 = np.maximum(cells.min(axis=0), 0)
        c1 = min(int(cells[:, 0].max()) + 1, total.width)
        r1 = min(int(cells[:, 1].max()) + 1, total.height)
        if c0 >= c1 or r0 >= r1:
            return
        xs = self._base[0] + (np.arange(c0, c1) + self._shift[0] + 0.5) * res - pose[0]
        ys = self._base[1] + (np.arange(r0, r1) + self._shift[1] + 0.5) * res - pose[1]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        lx = c * xs[None, :] + s * ys[:, None]
        ly = -s * xs[None, :] + c * ys[:, None]
        lc = np.floor((lx - local.origin_x) / res).astype(np.int64)
        lr = np.floor((ly - local.origin_y) / res).astype(np.int64)
        inside = (lc >= 0) & (lc < local.width) & (lr >= 0) & (lr < local.height)
        values = np.zeros(lc.shape, dtype=np.float32)
        values[inside] = local.log_odds[lr[inside], lc[inside]]
        observed = values != 0
        window = total.log_odds[r0:r1, c0:c1]
        window[observed] += sign * values[observed]
        counts = self.seen[r0:r1, c0:c1]
        counts[observed] += sign
        window[counts == 0] = 0.0

    # -- reading ----------------------------------------------------------------------------

    def grid(self) -> OccupancyGrid:
        """The composed map (clamped log-odds; unknown where no submap saw a cell); rebuilt
        only when a compose() changed something."""
        if not self._changed:
            return self.view
        total = self.total
        view = OccupancyGrid(self.resolution, max(self.max_cells, total.width * total.height),
                             initial_size=self.resolution)
        lo = np.clip(total.log_odds, view.min_log_odds, view.max_log_odds)
        lo[(lo == 0) & (self.seen > 0)] = OBSERVED_EPSILON
        lo[self.seen == 0] = 0.0
        view.log_odds = lo.astype(np.float32)
        view.width, view.height = total.width, total.height
        view.origin_x, view.origin_y = total.origin_x, total.origin_y
        view.dropped_points = sum(s.grid.dropped_points for s in self.submaps)
        view = view.cropped()  # the sum grows with margins; the map is what was seen
        view.version = self.view.version + 1
        self.view = view
        self._changed = False
        return view

    @property
    def nbytes(self) -> int:
        return (sum(s.grid.nbytes for s in self.submaps) + self.total.nbytes
                + int(self.seen.nbytes))


def compose_poses(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``compose(a[i], b[i])`` for arrays (n, 3)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.column_stack([a[:, 0] + c * b[:, 0] - s * b[:, 1],
                            a[:, 1] + s * b[:, 0] + c * b[:, 1], a[:, 2] + b[:, 2]])


def relative_poses(anchors: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """``between(anchors[i], poses[i])`` for arrays (n, 3)."""
    dx, dy = poses[:, 0] - anchors[:, 0], poses[:, 1] - anchors[:, 1]
    c, s = np.cos(anchors[:, 2]), np.sin(anchors[:, 2])
    turn = np.remainder(poses[:, 2] - anchors[:, 2] + math.pi, math.tau) - math.pi
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, turn])


def _pose(row: np.ndarray) -> Pose2:
    return (float(row[0]), float(row[1]), float(row[2]))
