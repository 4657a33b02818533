# Seeds of the default arena, ten simulated minutes of wander each, through `arbiterd simulate`
# in parallel processes: no collision, a useful speed, the coverage reported.
from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import pytest

from tests.support.paths import REPO

#: CI runs seeds 1-8; ARBITERD_WANDER_SEEDS=20 runs the twenty of docs/autonomy.md's table
SEEDS = range(1, 1 + int(os.environ.get("ARBITERD_WANDER_SEEDS", "8")))
SECONDS = 600


def wander(seed: int) -> dict[str, Any]:
    result = subprocess.run(
        [sys.executable, "-m", "daemon.cli", "simulate", "--seconds", str(SECONDS), "--seed",
         str(seed), "--autonomy", "wander", "--json"],
        cwd=REPO, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr
    run: dict[str, Any] = json.loads(result.stdout)
    return run


@pytest.mark.timeout(1800)
def test_seeds_of_ten_minutes_wander() -> None:
    with ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 2)) as pool:
        runs = list(pool.map(wander, SEEDS))
    table = "\n".join(
        f"seed {r['seed']:2}: collisions {r['collisions']}, mean {r['mean_speed_m_s']:.3f} m/s,"
        f" coverage {r['coverage']['fraction']:.2f}, nearest {r['min_clearance_m']:.3f} m, "
        f"{r['realtime_factor']}x" for r in runs)
    print(table)
    for run in runs:
        assert run["seconds"] == SECONDS and run["autonomy"]["mode"] == "wander", table
        assert run["collisions"] == 0, table
        assert run["wheel_guard"]["trips"] == 0, run["wheel_guard"]  # no false mismatch stop
        assert run["mean_speed_m_s"] >= 0.25, table
        assert 0.0 < run["coverage"]["fraction"] <= 1.0, table
        assert run["min_clearance_m"] > 0.0, table
        times = run["autonomy"]["state_times_s"]
        assert sum(times.values()) == pytest.approx(SECONDS, abs=0.5), table
    assert len({r["path_length_m"] for r in runs}) == len(runs)  # twenty different arenas
