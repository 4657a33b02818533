# Benchmark suite "localize": from a wrong initial pose (1 m / 30°) on a saved map to the truth.
from __future__ import annotations

import asyncio
import logging
import math
import statistics
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon.bench import BenchResult
from daemon.bench.mapping_sim import DRIFT
from daemon.config import load_config
from daemon.lockstep.runner import Lockstep

SUITE = "localize"
WORLD = "apartment"
MAP_NAME = "bench"
#: the wrong initial pose: this far off, in a direction that turns with the trial, and this
#: much heading error (alternating sign)
OFFSET_M = 1.0
HEADING_DEG = 30.0
DRIVE_S = 5.0
TARGET_M = 0.05
MAP_SEED = 1


@dataclass(frozen=True)
class Trial:
    """One localisation run: when the error last came down to the target (s after the
    start, inf if it did not) and the error at the end of the drive."""

    seed: int
    converged_s: float
    final_m: float
    final_deg: float
    revolutions: int


def build_map(directory: Path, seconds: float) -> dict[str, Any]:
    """Map the world with the drifting base (wander) and save it as MAP_NAME in directory;
    the map frame is the frame of the world's start pose."""
    config = load_config(None, sim=True, env={})
    config.update("sim", {**DRIFT, "world_file": WORLD, "seed": MAP_SEED})
    runner = Lockstep(config, autonomy="wander", mapping=True,
                      map_out=str(directory / MAP_NAME))
    report: dict[str, Any] = asyncio.run(runner.run(seconds))["mapping"]
    return report


def initial_error(trial: int, trials: int) -> tuple[float, float, float]:
    """The trial's initial pose in the map (the truth there is the origin)."""
    bearing = math.tau * trial / trials
    heading = HEADING_DEG if trial % 2 == 0 else -HEADING_DEG
    return (OFFSET_M * math.cos(bearing), OFFSET_M * math.sin(bearing), heading)


def run_trial(directory: Path, trial: int, trials: int, seconds: float = DRIVE_S) -> Trial:
    """Localise in the saved map from a pose 1 m / 30° off while wandering for ``seconds``."""
    seed = 100 + trial
    config = load_config(None, sim=True, env={})
    config.update("sim", {**DRIFT, "world_file": WORLD, "seed": seed})
    config.update("mapping", {"mode": "localize", "map": MAP_NAME, "directory": str(directory),
                              "initial_pose": list(initial_error(trial, trials))})
    runner = Lockstep(config, autonomy="wander", mapping=True)
    asyncio.run(runner.run(seconds))
    assert runner.mapping is not None
    series = runner.mapping.series
    converged = math.inf
    for stamp, error_m, _ in reversed(series):
        if error_m > TARGET_M:
            break
        converged = stamp
    _, final_m, final_rad = series[-1] if series else (0.0, math.inf, math.inf)
    return Trial(seed, converged, final_m, math.degrees(final_rad), len(series))


def run(quick: bool) -> list[BenchResult]:
    logging.getLogger("arbiterd").setLevel(logging.ERROR)
    trials = 5 if quick else 20
    with tempfile.TemporaryDirectory(prefix="arbiterd-localize-") as tmp:
        directory = Path(tmp)
        built = build_map(directory, 120.0 if quick else 240.0)
        runs = [run_trial(directory, i, trials) for i in range(trials)]
    ok = [t for t in runs if t.converged_s <= DRIVE_S]
    times = sorted(t.converged_s for t in runs)
    note = (f"{WORLD}, map from {120 if quick else 240} s of wander with the drifting base "
            f"(its pose error RMS {built['pose_error']['rms_m']:.3f} m, precision/recall "
            f"{built['map']['precision']:.3f}/{built['map']['recall']:.3f}); each trial "
            f"starts {OFFSET_M:g} m / {HEADING_DEG:g}° off, in a different direction, and "
            "wanders (2 % calibration error + slip)")
    worst = max(t.final_m for t in runs)
    worst_deg = max(t.final_deg for t in runs)
    mean_m = statistics.fmean(t.final_m for t in runs)
    return [
        BenchResult(SUITE, f"trials within {TARGET_M} m in {DRIVE_S:g} s", len(ok), "of "
                    f"{trials}", f"{trials} of {trials}", len(ok) == trials, note),
        BenchResult(SUITE, "time to converge, median", round(statistics.median(times), 2), "s",
                    f"<= {DRIVE_S:g}", times[len(times) // 2] <= DRIVE_S,
                    f"max {times[-1]:.2f} s (inf: not converged)"),
        BenchResult(SUITE, "position error at the end, worst", round(worst, 4), "m",
                    f"<= {TARGET_M}", worst <= TARGET_M,
                    f"heading worst {worst_deg:.2f}°; mean {mean_m:.4f} m"),
    ]
