# SLAM benchmark: the mapper over the Freiburg logs, relation errors beside published figures.
from __future__ import annotations

import argparse
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

    ours: RelationErrors  # after the offline refinement of the trajectory
    online: RelationErrors  # the trajectory as the mapper made it (after a final optimisation)
    odometry: RelationErrors
    wall_s: float  # mapping, the final optimisation, far loops and the refinement
    refine_s: float  # the far-loop search and the refinement
    duration_s: float
    per_scan_s: list[float]
    far_loops: dict[str, int]  # the offline far-in-time loop search's counts


def run_dataset(name: str, config: MapperConfig = BENCH_CONFIG,
                root: Path = DATA_ROOT, perturb: float = 0.0) -> Run:
    """Map the whole log (scans read beforehand; every point scaled by 1 + ``perturb``),
    optimise once at the end, refine the trajectory offline, then evaluate."""
    dataset = freiburg_dataset(root, name)
    scans = [(stamp, odom, points * (1.0 + perturb)) for stamp, odom, points
             in read_scans(dataset.log, max_range=config.max_range)]
    relations = load_relations(dataset.relations)
    mapper = Mapper(config)
    per_scan: list[float] = []
    start = time.perf_counter()
    for stamp, odom, points in scans:
        before = time.perf_counter()
        mapper.add_scan(odom, points, stamp)
        per_scan.append(time.perf_counter() - before)
    mapper.optimize()
    online = mapper.trajectory
    refine_start = time.perf_counter()
    far = mapper.close_far_loops()
    refined = mapper.refined_trajectory([points for _, _, points in scans],
                                        odometry=[odom for _, odom, _ in scans])
    end = time.perf_counter()
    return Run(relation_errors(refined, relations), relation_errors(online, relations),
               relation_errors([(s, o) for s, o, _ in scans], relations),
               end - start, end - refine_start, scans[-1][0] - scans[0][0], per_scan, far)


def results_of(name: str, run: Run) -> list[BenchResult]:
    carto_t, carto_r, gm_t, gm_r = PUBLISHED[name]
    trans, rot = run.ours.trans.mean, math.degrees(run.ours.rot.mean)
    published = f"Cartographer {carto_t} m / {carto_r}°, graph mapping {gm_t} m / {gm_r}°"
    odometry = (f"odometry alone {run.odometry.trans.mean:.4f} m / "
                f"{math.degrees(run.odometry.rot.mean):.3f}°")
    speed = run.duration_s / run.wall_s
    online = (f"online (before the refinement) {run.online.trans.mean:.4f} m / "
              f"{math.degrees(run.online.rot.mean):.3f}°")
    return [
        BenchResult(SUITE, f"{name}: mean abs translational error", round(trans, 4), "m",
                    f"<= {carto_t} (1.5x: {1.5 * carto_t:.4f})", trans <= 1.5 * carto_t,
                    f"± {run.ours.trans.std:.4f}; {published}; {odometry}; {online}"),
        BenchResult(SUITE, f"{name}: mean abs rotational error", round(rot, 3), "deg",
                    f"<= {carto_r} (1.5x: {1.5 * carto_r:.3f})", rot <= 1.5 * carto_r,
                    f"± {math.degrees(run.ours.rot.std):.3f}; {run.ours.trans.n} relations"),
        BenchResult(SUITE, f"{name}: odometry alone, translational / rotational",
                    round(run.odometry.trans.mean, 4), "m",
                    note=f"{math.degrees(run.odometry.rot.mean):.3f}° (the in-run baseline)"),
        BenchResult(SUITE, f"{name}: speed", round(speed, 1), "x real time",
                    f">= {SPEED_TARGET}", speed >= SPEED_TARGET,
                    f"{run.wall_s:.1f} s for {run.duration_s:.0f} s of data, of which the "
                    f"refinement {run.refine_s:.1f} s (far loops: "
                    f"{', '.join(f'{k} {v}' for k, v in run.far_loops.items())})"),
        BenchResult(SUITE, f"{name}: time per scan, median", round(
            float(np.median(run.per_scan_s)) * 1e3, 3), "ms",
            note=f"p95 {np.percentile(run.per_scan_s, 95) * 1e3:.1f} ms; all of add_scan "
                 f"(matching, key scans, loop closures, optimisations)"),
    ]


def run(quick: bool, names: list[str] | None = None,
        perturb: float = 0.0) -> list[BenchResult]:
    """Every Freiburg log, or those ``names`` (quick: MIT CSAIL, the shortest)."""
    if not DATA_ROOT.is_dir():
        return [BenchResult(SUITE, "Freiburg data (absent)", math.nan, "",
                            note=f"expected at {DATA_ROOT}")]
    names = names or (["mit-csail"] if quick else list(PUBLISHED))
    results: list[BenchResult] = []
    for name in names:
        results += results_of(name, run_dataset(name, perturb=perturb))
    return results


def main(argv: list[str] | None = None) -> int:
    """``python -m daemon.bench.slam [DATASET ...] [--perturb EPS]``: some of the logs."""
    from daemon.bench.runner import format_table, missed_summary

    parser = argparse.ArgumentParser(prog="python -m daemon.bench.slam",
                                     description="The slam suite on some of the Freiburg logs.")
    parser.add_argument("datasets", nargs="*", metavar="DATASET",
                        help=f"any of {', '.join(PUBLISHED)} (default: all)")
    parser.add_argument("--perturb", type=float, default=0.0, metavar="EPS",
                        help="scale every scan point by 1 + EPS (the logs are chaotic in their "
                             "input: compare versions over several EPS, e.g. 1e-12)")
    args = parser.parse_args(argv)
    unknown = [name for name in args.datasets if name not in PUBLISHED]
    if unknown:
        parser.error(f"unknown dataset {unknown[0]!r}; datasets: {', '.join(PUBLISHED)}")
    results = run(False, list(args.datasets) or None, args.perturb)
    print(format_table(results))
    print(missed_summary(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
