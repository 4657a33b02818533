# Vectorised ray casting against wall segments and circles (numpy), for the simulated lidar.
from __future__ import annotations

import copy
import math

import numpy as np

from sim.world import World

#: Default lidar geometry: 360 rays at 1°, 0.1-10 m.
DEFAULT_RAYS = 360
DEFAULT_RANGE_MIN = 0.1
DEFAULT_RANGE_MAX = 10.0
#: a wall's free end is seen as a disc this wide (m): a real wall has a thickness, and a
#: zero-thickness segment met end-on would hide from every ray (a ray along it is degenerate)
END_CAP_RADIUS = 0.005


def ray_angles(count: int = DEFAULT_RAYS) -> np.ndarray:
    """``count`` ray angles evenly spaced over a full turn, starting straight ahead (rad)."""
    return np.arange(count, dtype=float) * (2.0 * math.pi / count)


def cast(world: World, x: float, y: float, theta: float, angles: np.ndarray,
         range_min: float = DEFAULT_RANGE_MIN,
         range_max: float = DEFAULT_RANGE_MAX) -> np.ndarray:
    """Ranges from (x, y) along ``theta + angles`` (counter-clockwise, rad) to the world.

    A ray with nothing between ``range_min`` and ``range_max`` gives ``inf`` (no return).
    """
    return RayCaster(world, angles, range_min, range_max).cast(x, y, theta)


class RayCaster:
    """Casts a fixed fan of rays (angles relative to the robot's heading) into a world.

    Per cast, the few world primitives are moved into the robot frame (one 2x2 rotation of a
    handful of precomputed vectors), so the ray directions are fixed; then one small matrix
    product gives every ray-primitive term at once, and the hits are elementwise work on
    ``primitives x rays`` arrays reduced over the primitives.
    """

    def __init__(self, world: World, angles: np.ndarray,
                 range_min: float = DEFAULT_RANGE_MIN,
                 range_max: float = DEFAULT_RANGE_MAX) -> None:
        if not 0 <= range_min < range_max:
            raise ValueError(f"need 0 <= range_min < range_max, got {range_min}, {range_max}")
        self.world = world
        self.angles = np.asarray(angles, dtype=float)
        self.range_min = range_min
        self.range_max = range_max
        self._directions = np.stack([np.cos(self.angles), np.sin(self.angles)])  # 2 x rays
        seg, cir = world.segment_array, np.concatenate([world.circle_array, _end_caps(world)])
        a, e = seg[:, 0:2], seg[:, 2:4] - seg[:, 0:2]
        self._n_seg = len(seg)
        # rows (world frame) whose products with a ray direction d are dxe, axd and d·c;
        # the robot position enters as an offset that is linear in (x, y)
        self._rows = np.concatenate([_perp(e), -_perp(a), cir[:, 0:2]])
        zeros, ones = np.zeros(len(seg)), np.ones(len(seg))
        ones_c, zeros_c = np.ones(len(cir)), np.zeros(len(cir))
        self._x_coef = np.concatenate([np.stack([zeros, zeros], 1), np.stack([zeros, ones], 1),
                                       np.stack([ones_c, zeros_c], 1)])
        self._y_coef = np.concatenate([np.stack([zeros, zeros], 1), np.stack([-ones, zeros], 1),
                                       np.stack([zeros_c, ones_c], 1)])
        self._a_cross_e = a[:, 0] * e[:, 1] - a[:, 1] * e[:, 0]
        self._e = e
        self._centres = cir[:, 0:2]
        self._radius2 = cir[:, 2] ** 2

    def with_angles(self, angles: np.ndarray) -> RayCaster:
        """The same world and ranges along another fan of rays, sharing the precomputed
        geometry (a device whose rays move every sample casts a new fan each time)."""
        caster = copy.copy(self)
        caster.angles = np.asarray(angles, dtype=float)
        caster._directions = np.stack([np.cos(caster.angles), np.sin(caster.angles)])
        return caster

    def cast(self, x: float, y: float, theta: float) -> np.ndarray:
        """Ranges for the robot at (x, y) heading ``theta``; ``inf`` where nothing is hit.

        The origin must be outside every circle (the robot's footprint guarantees it).
        """
        cos_t, sin_t = math.cos(theta), math.sin(theta)
        rot = np.array([[cos_t, -sin_t], [sin_t, cos_t]])  # robot -> world; row @ rot = inverse
        rows = (self._rows - self._x_coef * x - self._y_coef * y) @ rot
        products = rows @ self._directions
        n = self._n_seg
        with np.errstate(divide="ignore", invalid="ignore"):
            if n:
                # (a - o)xe is the same in every frame
                a_cross_e = self._a_cross_e - (x * self._e[:, 1] - y * self._e[:, 0])
                ranges = _segment_hits(products[:n], products[n:2 * n], a_cross_e)
            else:
                ranges = np.full(products.shape[1], np.inf)
            if len(self._centres):
                offset = ((self._centres - (x, y)) ** 2).sum(axis=1) - self._radius2
                np.minimum(ranges, _circle_hits(products[2 * n:], offset), out=ranges)
        ranges[(ranges < self.range_min) | (ranges > self.range_max)] = np.inf
        return ranges


def _perp(v: np.ndarray) -> np.ndarray:
    """Each row (vx, vy) turned into (vy, -vx), so that d·perp(v) = dxv."""
    return np.stack([v[:, 1], -v[:, 0]], axis=1)


def _segment_hits(d_cross_e: np.ndarray, a_cross_d: np.ndarray,
                  a_cross_e: np.ndarray) -> np.ndarray:
    """Nearest hit distance per ray over all segments (segments x rays; rays from the origin).

    The ray t·d meets the segment a + u·e where t = (axe)/(dxe) and u = (axd)/(dxe); a ray
    parallel to a segment (dxe = 0) gives inf or nan and counts as no hit.
    """
    t = a_cross_e[:, None] / d_cross_e
    u = a_cross_d / d_cross_e
    t[~((u >= 0) & (u <= 1) & (t > 0))] = np.inf
    return np.asarray(t.min(axis=0))


def _circle_hits(along: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Nearest hit distance per ray over all circles (circles x rays), from outside them.

    ``along`` is d·c (ray direction onto the centre), ``offset`` is |c|² - r² per circle; the
    near root of t² - 2·along·t + offset = 0 is along - sqrt(along² - offset) (nan: a miss).
    """
    root = np.sqrt(along * along - offset[:, None])
    t = along - root
    t[~(t > 0)] = np.inf
    return np.asarray(t.min(axis=0))


def _end_caps(world: World) -> np.ndarray:
    """A small disc at every wall end no other wall shares: ``(N, 3)`` circles."""
    seg = world.segment_array
    if not len(seg):
        return np.zeros((0, 3))
    ends = np.concatenate([seg[:, 0:2], seg[:, 2:4]])
    keys = np.round(ends / 1e-6).astype(np.int64)
    _, index, counts = np.unique(keys, axis=0, return_index=True, return_counts=True)
    free = ends[index[counts == 1]]
    return np.column_stack([free, np.full(len(free), END_CAP_RADIUS)])
