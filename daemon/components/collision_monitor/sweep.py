# Swept footprint: how far the robot can follow a constant-twist path before touching a point.
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]

TWO_PI = 2.0 * math.pi
#: |sin psi| below this is a straight line (the turning centre is at infinity)
STRAIGHT = 1e-9
#: metres of travel one radian of turning counts as in a path direction
SCALE = 1.0


def path_direction(linear: float, angular: float) -> tuple[float, float]:
    """``(psi, sigma)`` of a twist: its path direction ``atan2(w, v)`` (one rad/s weighs as
    much as one m/s) and its speed ``hypot(v, w)`` along that path in travel units per second.
    A twist keeps its path (its curvature and sense) when scaled."""
    return math.atan2(SCALE * angular, linear), math.hypot(linear, SCALE * angular)


def contact_travel(psis: Sequence[float], px: Array, py: Array, discs: Array,
                   horizon: float) -> Array:
    """Travel along each path direction before each disc first touches each point,
    ``(K, D, N)`` for K directions, D discs and N points.

    Along direction ``psi`` the robot follows the twist ``(cos psi, sin psi / SCALE)`` (see
    :func:`path_direction`), one travel unit per second; ``discs`` ``(D, 3)`` (centre x,
    centre y, radius, robot frame) move with it. A point already inside a disc blocks (0)
    only when the motion brings them closer, else it is left behind. ``inf`` beyond
    ``horizon`` or never.
    """
    out = np.empty((len(psis), len(discs), len(px)))
    arcs = [i for i, psi in enumerate(psis) if abs(math.sin(psi)) >= STRAIGHT]
    cx, cy, r = discs[:, 0:1], discs[:, 1:2], discs[:, 2:3]
    for i, psi in enumerate(psis):
        if i not in arcs:
            out[i] = _straight(math.copysign(1.0, math.cos(psi)), px[None, :] - cx,
                               py[None, :] - cy, r)
    if arcs:
        angle = np.array([psis[i] for i in arcs])
        out[arcs] = _arc(np.cos(angle), np.sin(angle) / SCALE, px, py, discs)
    out[out > horizon] = np.inf
    return out


def _straight(direction: float, qx: Array, qy: Array, r: Array) -> Array:
    """Straight along ``direction`` * x: first contact distance of each disc and point."""
    along = direction * qx
    half = np.sqrt(np.maximum(r * r - qy * qy, 0.0))
    reach = np.abs(qy) < r  # a point grazed side-on is never closed in on
    near = along - half
    travel = np.where(reach & (near >= 0), near, np.inf)
    inside = reach & (near < 0) & (along + half > 0)
    return np.asarray(np.where(inside & (along > 0), 0.0, travel))


def _arc(v: Array, w: Array, px: Array, py: Array, discs: Array) -> Array:
    """Rotation about each turning centre (0, v/w): the time (= travel, the path's speed is
    one unit) until first contact, ``(K, D, N)``."""
    icr = (v / w)[:, None, None]
    cx, cy, r = discs[None, :, 0:1], discs[None, :, 1:2], discs[None, :, 2:3]
    ux, uy = cx, cy - icr
    qx, qy = px[None, None, :], py[None, None, :] - icr
    u, q = np.hypot(ux, uy), np.hypot(qx, qy)
    with np.errstate(divide="ignore", invalid="ignore"):
        # |u| - |q| without subtracting two radii that may be ~1/w (a near-straight arc)
        gap = ((ux - qx) * (ux + qx) + (cy - py[None, None, :]) * (uy + qy)) / (u + q)
        # the half-window of rotation angles in which the point is inside the disc, from
        # 1 - cos(half) = (r^2 - gap^2) / (2 |u| |q|): the law of cosines, cancellation-free
        reach = r * r - gap * gap
        half = 2.0 * np.arcsin(np.minimum(np.sqrt(np.maximum(reach, 0.0) / (4.0 * u * q)),
                                          1.0))
        # angle from the disc centre to the point about the turning centre, in the turn's
        # sense
        alpha = np.arctan2(ux * qy - uy * qx, ux * qx + uy * qy)
        alpha *= np.sign(w)[:, None, None]
        angle = np.mod(alpha - half, TWO_PI)
        angle[(alpha > 0) & (alpha < half)] = 0.0  # inside and closing in
        angle[~(reach > 0) | ~(u * q > 0)] = np.inf  # out of reach, or on the turning centre
        angle /= np.abs(w)[:, None, None]
    return angle
