# Synthetic rooms for the SLAM tests: wall segments and a numpy ray caster in the robot's frame.
from __future__ import annotations

import math

import numpy as np

from slam.pose import Pose2

# an L-shaped 8 x 6 m room with a pillar and a wall stub: asymmetric, so poses are unambiguous
ROOM = np.array([
    [0, 0, 8, 0], [8, 0, 8, 4], [8, 4, 5, 4], [5, 4, 5, 6], [5, 6, 0, 6], [0, 6, 0, 0],
    [2, 2, 2.5, 2], [2.5, 2, 2.5, 2.6], [2.5, 2.6, 2, 2.6], [2, 2.6, 2, 2],
    [6, 1.5, 6, 2.5], [3.5, 4.5, 4.2, 5.0],
], dtype=np.float64)


def cast(pose: Pose2, beams: int = 360, walls: np.ndarray = ROOM,
         max_range: float = 12.0) -> np.ndarray:
    """Points (N, 2) in the robot frame where beams from ``pose`` first hit a wall."""
    angles = np.linspace(-math.pi, math.pi, beams, endpoint=False)
    world = angles + pose[2]
    dx, dy = np.cos(world)[:, None], np.sin(world)[:, None]
    ax, ay = walls[:, 0][None, :], walls[:, 1][None, :]
    ex, ey = (walls[:, 2] - walls[:, 0])[None, :], (walls[:, 3] - walls[:, 1])[None, :]
    px, py = ax - pose[0], ay - pose[1]
    denom = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (px * ey - py * ex) / denom  # distance along the beam
        u = (px * dy - py * dx) / denom  # position along the wall
    hit = (np.abs(denom) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
    dist = np.where(hit, t, np.inf).min(axis=1)
    ok = dist <= max_range
    return np.column_stack([dist[ok] * np.cos(angles[ok]), dist[ok] * np.sin(angles[ok])])
