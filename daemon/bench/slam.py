# SLAM benchmark: the mapper over the Freiburg logs, relation errors beside published figures.
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from daemon.bench import BenchResult
from slam.datasets import freiburg_dataset, read_scans
from slam.mapper import Mapper, MapperConfig
from slam.relations import RelationErrors, load_relations, relation_errors

SUITE = "slam"
DATA_ROOT = Path(__file__).resolve().parents[2].parent / "shared" / "datasets" / "slam"
SPEED_TARGET = 10.0  # x real time
MS_TARGET = 5.0  # median ms per scan (matching + integration), 360-ray revolutions
# Freiburg logs carry 180°-wide scans out to 50-80 m; the robot default (12 m, an RPLIDAR A1)
# would throw away most of the structure of these large buildings.
BENCH_CONFIG = MapperConfig(max_range=30.0)
# mean abs translational (m) / rotational (deg) error: Cartographer (Hess et al. 2016, Table II)
# and graph mapping (Kuemmerle et al. 2009, as quoted there)
PUBLISHED: dict[str, tuple[float, float, float, float]] = {
    "aces": (0.0375, 0.373, 0.044, 0.4),
    "mit-csail": (0.0319, 0.369, 0.004, 0.05),
    "fr079": (0.0452, 0.538, 0.056, 0.6),
    "intel": (0.0229, 0.453, 0.031, 1.3),
    "fr-clinic": (0.1078, 0.747, 0.143, 0.9),
}


@dataclass
class Run:
    """One dataset through the mapper."""

    ours: RelationErrors
    odometry: RelationErrors
    wall_s: float
    duration_s: float
    per_scan_s: list[float]


def run_dataset(name: str, config: MapperConfig = BENCH_CONFIG,
                root: Path = DATA_ROOT) -> Run:
    """Map the whole log (scans read beforehand), optimise once at the end, then evaluate."""
    dataset = freiburg_dataset(root, name)
    scans = list(read_scans(dataset.log, max_range=config.max_range))
    relations = load_relations(dataset.relations)
    mapper = Mapper(config)
    per_scan: list[float] = []
    start = time.perf_counter()
    for stamp, odom, points in scans:
        before = time.perf_counter()
        mapper.add_scan(odom, points, stamp)
        per_scan.append(time.perf_counter() - before)
    mapper.optimize()
    wall = time.perf_counter() - start
    return Run(relation_errors(mapper.trajectory, relations),
               relation_errors([(s, o) for s, o, _ in scans], relations),
               wall, scans[-1][0] - scans[0][0], per_scan)


def results_of(name: str, run: Run) -> list[BenchResult]:
    carto_t, carto_r, gm_t, gm_r = PUBLISHED[name]
    trans, rot = run.ours.trans.mean, math.degrees(run.ours.rot.mean)
    published = f"Cartographer {carto_t} m / {carto_r}°, graph mapping {gm_t} m / {gm_r}°"
    odometry = (f"odometry alone {run.odometry.trans.mean:.4f} m / "
                f"{math.degrees(run.odometry.rot.mean):.3f}°")
    speed = run.duration_s / run.wall_s
    return [
        BenchResult(SUITE, f"{name}: mean abs translational error", round(trans, 4), "m",
                    f"<= {carto_t} (1.5x: {1.5 * carto_t:.4f})", trans <= 1.5 * carto_t,
                    f"± {run.ours.trans.std:.4f}; {published}; {odometry}"),
        BenchResult(SUITE, f"{name}: mean abs rotational error", round(rot, 3), "deg",
                    f"<= {carto_r} (1.5x: {1.5 * carto_r:.3f})", rot <= 1.5 * carto_r,
                    f"± {math.degrees(run.ours.rot.std):.3f}; {run.ours.trans.n} relations"),
        BenchResult(SUITE, f"{name}: odometry alone, translational / rotational",
                    round(run.odometry.trans.mean, 4), "m",
                    note=f"{math.degrees(run.odometry.rot.mean):.3f}° (the in-run baseline)"),
        BenchResult(SUITE, f"{name}: speed", round(speed, 1), "x real time",
                    f">= {SPEED_TARGET}", speed >= SPEED_TARGET,
                    f"{run.wall_s:.1f} s for {run.duration_s:.0f} s of data"),
        BenchResult(SUITE, f"{name}: time per scan, median", round(
            float(np.median(run.per_scan_s)) * 1e3, 3), "ms",
            note=f"p95 {np.percentile(run.per_scan_s, 95) * 1e3:.1f} ms; all of add_scan "
                 f"(matching, key scans, loop closures, optimisations)"),
    ]


def run(quick: bool) -> list[BenchResult]:
    """Every Freiburg log (quick: MIT CSAIL, the shortest)."""
    if not DATA_ROOT.is_dir():
        return [BenchResult(SUITE, "Freiburg data (absent)", math.nan, "",
                            note=f"expected at {DATA_ROOT}")]
    names = ["mit-csail"] if quick else list(PUBLISHED)
    results: list[BenchResult] = []
    for name in names:
        results += results_of(name, run_dataset(name))
    return results
