# Polar free-space histogram: how far the robot could drive straight toward each sector.
from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]


class Sectors:
    """``count`` directions evenly spaced counter-clockwise from straight ahead (rad, robot
    frame). For each, :meth:`free` gives the distance a disc could travel straight that way
    before touching a scan point, capped at ``look``, for a comfortable disc (``half_width``)
    and a tight one (``tight_width``, what the robot needs at the least): a VFH-style
    histogram over directions of the space the whole robot needs, not of single rays."""

    def __init__(self, count: int, half_width: float, look: float,
                 tight_width: float | None = None) -> None:
        self.count = count
        self.half_width = half_width
        self.tight_width = half_width if tight_width is None else tight_width
        self.look = look
        angles = np.arange(count) * (2.0 * math.pi / count)
        self.angles: Array = np.where(angles > math.pi, angles - 2.0 * math.pi, angles)
        self._directions = np.stack([np.cos(self.angles), np.sin(self.angles)], axis=1)
        self._widths = np.array([self.half_width, self.tight_width])[:, None, None]

    def free(self, px: Array, py: Array) -> Array:
        """Free straight-line travel per direction, ``(2, count)``: comfortable, tight (m, 0
        when already touching)."""
        r2 = px * px + py * py
        near = r2 <= (self.look + self.half_width) ** 2
        if not near.any():
            return np.full((2, self.count), self.look)
        along = self._directions @ np.stack([px[near], py[near]])  # sectors x points
        lateral2 = r2[near][None, :] - along * along
        width2 = self._widths * self._widths
        half = np.sqrt(np.maximum(width2 - lateral2, 0.0))
        hit = (lateral2 < width2) & (along + half > 0.0)
        distance = np.where(hit, along - half, np.inf).min(axis=2)
        return np.asarray(np.clip(distance, 0.0, self.look))

    def index(self, angle: float) -> int:
        """The sector nearest to ``angle`` (rad, robot frame)."""
        return round((angle % (2.0 * math.pi)) / (2.0 * math.pi / self.count)) % self.count
