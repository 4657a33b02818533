# `arbiterd simulate`: scripted full-speed drives at a wall, an obstacle and into a corner, a
# stalled lidar, determinism, the CSV, and errors - all through the real command line.
from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from daemon.components.collision_monitor.settings import CollisionMonitorSettings
from tests.support.paths import REPO

SCENARIOS = REPO / "tests" / "scenarios"
STOP_MARGIN = CollisionMonitorSettings.stop_margin_m


def simulate(*args: str, expect: int = 0) -> subprocess.CompletedProcess[str]:
    result = subprocess.run([sys.executable, "-m", "daemon.cli", "simulate", *args],
                            cwd=REPO, capture_output=True, text=True, timeout=300)
    assert result.returncode == expect, result.stderr
    return result


def metrics(*args: str) -> dict[str, Any]:
    out: dict[str, Any] = json.loads(simulate(*args, "--json").stdout)
    return out


def mark(run: dict[str, Any], label: str) -> dict[str, Any]:
    found: dict[str, Any] = next(m for m in run["marks"] if m["label"] == label)
    return found


@pytest.mark.parametrize("world", ["wall", "obstacle", "corner"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_full_speed_drive_stops_short_and_can_back_away(world: str, seed: int) -> None:
    run = metrics("--seconds", "9", "--seed", str(seed), "--world",
                  str(SCENARIOS / f"{world}.toml"), "--script",
                  str(SCENARIOS / "full_speed_then_back.toml"))
    assert run["collisions"] == 0
    assert run["max_speed_m_s"] >= 1.5  # it did drive fast before it had to slow down
    stopped, backed = mark(run, "stopped"), mark(run, "backed")
    assert abs(stopped["v"]) < 0.01 and stopped["safety"] == "stop"
    assert stopped["clearance_m"] >= STOP_MARGIN  # stopped short of the stop zone
    assert run["min_clearance_m"] >= STOP_MARGIN  # ... and never closer, ground truth
    moved = math.hypot(backed["x"] - stopped["x"], backed["y"] - stopped["y"])
    assert moved >= 0.4 and backed["clearance_m"] > stopped["clearance_m"] + 0.2  # backs away
    assert run["safety"]["entries"]["stop"] >= 1


def test_a_stalled_lidar_stops_the_robot() -> None:
    run = metrics("--seconds", "6", "--world", str(SCENARIOS / "wall.toml"), "--script",
                  str(SCENARIOS / "lidar_stall.toml"))
    stall, later = mark(run, "lidar"), mark(run, "later")
    assert stall["v"] > 0.7  # driving (still speeding up) when the revolutions stopped
    assert later["v"] == 0.0 and later["safety"] == "stop"
    assert run["final"]["x"] == later["x"]  # and it stays put while the scan is stale
    assert later["x"] - stall["x"] < 1.0 * 0.6 + 0.2  # timeout (0.5 s) + braking, not more
    assert run["collisions"] == 0
    assert run["lidar_revolutions"] <= 10


def test_same_seed_same_run_other_seed_other_run() -> None:
    args = ("--seconds", "60", "--autonomy", "wander")
    first, second = metrics(*args, "--seed", "4"), metrics(*args, "--seed", "4")
    other = metrics(*args, "--seed", "5")
    for run in (first, second, other):
        run.pop("wall_s")
        run.pop("realtime_factor")
    assert first == second
    assert first != other


def test_metrics_csv_and_the_human_report(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    report = simulate("--seconds", "20", "--autonomy", "wander", "--csv", str(path)).stdout
    for words in ("collisions", "path length", "mean speed", "smoothness", "coverage",
                  "autonomy", "CRUISE", "collision monitor"):
        assert words in report
    with path.open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 200  # [sim] metrics_rate 10 Hz for 20 s
    assert float(rows[-1]["t"]) == pytest.approx(20.0) and float(rows[-1]["path_length"]) > 1


def test_teleop_in_a_script_overrides_wander(tmp_path: Path) -> None:
    script = tmp_path / "override.json"
    script.write_text(json.dumps({"steps": [
        {"t": 5.0, "cmd_vel": {"linear": {"x": 0.0}}, "label": "teleop"},
        {"t": 6.0, "stop": True}]}))
    run = metrics("--seconds", "10", "--autonomy", "wander", "--script", str(script))
    assert run["autonomy"]["mode"] == "off" and run["autonomy"]["state"] == "IDLE"
    assert mark(run, "teleop")["v"] != 0.0 and run["final"]["clearance_m"] > 0
    assert run["autonomy"]["state_times_s"]["CRUISE"] <= 5.0


@pytest.mark.parametrize(("content", "message"), [
    ('[[step]]\nt = 1.0\n', "step[0]: expected exactly one of"),
    ('[[step]]\nt = 1.0\ncmd_vel = {linear = {y = 1.0}}\n', "linear.y"),
    ('[[step]]\nt = 2.0\nstop = true\n[[step]]\nt = 1.0\nstop = true\n', "time order"),
    ('[[step]]\nt = 1.0\nlidar = "unplug"\n', '"stall", "resume"'),
])
def test_script_errors_name_the_step(tmp_path: Path, content: str, message: str) -> None:
    script = tmp_path / "bad.toml"
    script.write_text(content)
    result = simulate("--seconds", "1", "--script", str(script), expect=2)
    assert message in result.stderr and str(script) in result.stderr


def test_a_bad_world_file_is_a_configuration_error(tmp_path: Path) -> None:
    world = tmp_path / "world.toml"
    world.write_text("circles = [{center = [0.0, 0.0], radius = -1.0}]\n")
    result = simulate("--seconds", "1", "--world", str(world), expect=78)
    assert "radius" in result.stderr
