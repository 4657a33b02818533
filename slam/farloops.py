# Offline loop closures between key scans far apart in time, found by odometry, checked in pairs.
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from slam.field import DistanceField
from slam.matcher import SearchWindow, correlative_search, match, subsample
from slam.pose import Pose2, between, compose, inverse, transform_points

Closure = tuple[int, int, Pose2, float]  # (older key, newer key, newer seen from older, score)


@dataclass(frozen=True)
class FarLoopConfig:
    """Tunables of the far-loop search (lengths in m, angles in rad, times in s).

    min_gap: only key scans at least this long apart in time are paired (a return to a place
        after a long tour, where the online search, which looks around the drifted pose, is
        out of reach).
    query_every: every this many key scans is a query.
    odometry_radius: a query's candidate is the far-in-time key scan nearest to it by the
        odometry's own poses (which drift slowly, not in the jumps bad matches make), if
        within this distance.
    online_reach: pairs the graph already puts this close were in reach of the online search.
    window: the wide correlative search around the odometry's relative pose (± m, ± rad).
    candidate_keys, query_keys: key scans on each side forming the two local submaps.
    submap_radius: submap points farther than this from its key scan are left out.
    min_score: a match scoring below this (0..1, the online matcher's score) is refused.
    agree: (m, rad) two closures agree when the loop they make through the graph's local
        chains closes to within this; ``agree_keys`` bounds how far apart (keys) their ends may
        be for that chain to be trusted, and a closure is kept with ``partners`` agreeing ones.
    min_correction: (m, rad) ... and only if the graph disagrees with it by more than this in
        translation or rotation: smaller corrections are the online search's business (on
        Intel, whose returns the online search closes, 14 agreeing closures of under this
        made the figures slightly worse).
    """

    min_gap: float = 1000.0
    query_every: int = 5
    odometry_radius: float = 15.0
    online_reach: float = 4.0
    window: tuple[float, float] = (16.0, math.radians(12))
    candidate_keys: int = 40
    query_keys: int = 3
    submap_radius: float = 25.0
    min_score: float = 0.35
    agree: tuple[float, float] = (0.5, math.radians(3))
    agree_keys: tuple[int, int] = (120, 60)
    partners: int = 2
    min_correction: tuple[float, float] = (1.0, math.radians(5))


def local_points(poses: np.ndarray, points: Sequence[np.ndarray], key: int, keys: int,
                 radius: float) -> np.ndarray:
    """The points of the key scans within ``keys`` of ``key``, in ``key``'s frame (by the
    graph's relative poses, which are right locally), within ``radius`` of it."""
    centre = (float(poses[key, 0]), float(poses[key, 1]), float(poses[key, 2]))
    parts = [transform_points(between(centre, (float(poses[k, 0]), float(poses[k, 1]),
                                               float(poses[k, 2]))),
                              np.asarray(points[k], dtype=np.float64))
             for k in range(max(0, key - keys), min(len(points), key + keys + 1))]
    out = np.vstack(parts) if parts else np.zeros((0, 2))
    return out[np.hypot(out[:, 0], out[:, 1]) <= radius]


def candidates(poses: np.ndarray, odometry: np.ndarray, stamps: np.ndarray,
               cfg: FarLoopConfig) -> list[tuple[int, int]]:
    """(older, newer) key pairs to check: per query, the far-in-time key scan nearest by
    odometry, unless the graph puts the two within the online search's reach."""
    pairs = []
    for j in range(0, len(stamps), cfg.query_every):
        old = np.nonzero(stamps[j] - stamps >= cfg.min_gap)[0]
        if len(old) == 0:
            continue
        gaps = np.hypot(*(odometry[old, :2] - odometry[j, :2]).T)
        best = int(np.argmin(gaps))
        i = int(old[best])
        if gaps[best] <= cfg.odometry_radius and \
                math.hypot(*(poses[i, :2] - poses[j, :2])) > cfg.online_reach:
            pairs.append((i, j))
    return pairs


def verify(poses: np.ndarray, points: Sequence[np.ndarray], odometry: np.ndarray,
           i: int, j: int, cfg: FarLoopConfig, sigma: float) -> Closure:
    """Key ``j``'s local submap matched against key ``i``'s over the wide window around the
    odometry's relative pose: coarse (0.4 m cells), then fine (0.05 m) and refined."""
    reference = local_points(poses, points, i, cfg.candidate_keys, cfg.submap_radius)
    query = local_points(poses, points, j, cfg.query_keys, cfg.submap_radius)
    coarse = DistanceField.from_points(reference, 0.4, 2.0, 1.2)
    fine = DistanceField.from_points(reference, 0.05, 1.0, 0.5)
    guess = between(tuple(odometry[i]), tuple(odometry[j]))
    sparse = subsample(query, 150)
    pose, _ = correlative_search(coarse, sparse, guess, SearchWindow(
        cfg.window[0], cfg.window[1], 0.4, math.radians(1), 0.4), penalty=0.0)
    pose, _ = correlative_search(fine, sparse, pose, SearchWindow(
        0.4, math.radians(1), 0.1, math.radians(0.25), 0.1), penalty=0.0)
    found = match(fine, query, pose, (SearchWindow(0.1, math.radians(0.5), 0.05,
                                                   math.radians(0.5), 0.1),),
                  sigma, search_points=150)
    return (i, j, found.pose, found.score)


def loop_error(poses: np.ndarray, a: Closure, b: Closure) -> tuple[float, float]:
    """How far the loop a's older key → a's newer → (graph) b's newer → b's older → (graph)
    a's older fails to close (m, rad)."""
    def at(k: int) -> Pose2:
        return (float(poses[k, 0]), float(poses[k, 1]), float(poses[k, 2]))
    cycle = compose(compose(compose(a[2], between(at(a[1]), at(b[1]))), inverse(b[2])),
                    between(at(b[0]), at(a[0])))
    return math.hypot(cycle[0], cycle[1]), abs(cycle[2])


def residual(poses: np.ndarray, closure: Closure) -> tuple[float, float]:
    """How far the graph's poses disagree with a closure (m, rad)."""
    i, j = closure[0], closure[1]
    seen = between((float(poses[i, 0]), float(poses[i, 1]), float(poses[i, 2])),
                   (float(poses[j, 0]), float(poses[j, 1]), float(poses[j, 2])))
    error = between(closure[2], seen)
    return math.hypot(error[0], error[1]), abs(error[2])


def corrects(poses: np.ndarray, closure: Closure, cfg: FarLoopConfig) -> bool:
    """Whether the graph disagrees with ``closure`` by more than ``cfg.min_correction``."""
    distance, angle = residual(poses, closure)
    return distance > cfg.min_correction[0] or angle > cfg.min_correction[1]


def consistent(poses: np.ndarray, closures: list[Closure], cfg: FarLoopConfig) -> list[Closure]:
    """The closures that at least ``partners`` others nearby agree with."""
    keep = []
    for a in closures:
        partners = 0
        for b in closures:
            if b is a or abs(b[0] - a[0]) > cfg.agree_keys[0] or \
                    abs(b[1] - a[1]) > cfg.agree_keys[1]:
                continue
            distance, angle = loop_error(poses, a, b)
            partners += distance <= cfg.agree[0] and angle <= cfg.agree[1]
        if partners >= cfg.partners:
            keep.append(a)
    return keep


def far_loops(poses: np.ndarray, points: Sequence[np.ndarray], odometry: np.ndarray,
              stamps: np.ndarray, cfg: FarLoopConfig,
              sigma: float) -> tuple[list[Closure], dict[str, int]]:
    """The far-in-time loop closures to add to the graph, and counts of what was tried."""
    pairs = candidates(poses, odometry, stamps, cfg)
    checked = [verify(poses, points, odometry, i, j, cfg, sigma) for i, j in pairs]
    strong = [c for c in checked if c[3] >= cfg.min_score]
    agreeing = consistent(poses, strong, cfg)
    kept = [c for c in agreeing if corrects(poses, c, cfg)]
    return kept, {"far_candidates": len(pairs), "far_strong": len(strong),
                  "far_agreeing": len(agreeing), "far_accepted": len(kept)}
