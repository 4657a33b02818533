# Tests of the run metrics: hand-computed smoothness figures, CSV rows, determinism.
from __future__ import annotations

import math
from pathlib import Path

import pytest

from sim.metrics import CSV_COLUMNS, RunMetrics
from sim.settings import SimConfig
from sim.stepper import SimWorld

# (at step, v m/s, w rad/s): a drive with starts, turns, a reverse and a collision course
SCRIPT = [(0, 0.5, 0.0), (100, 0.5, 0.6), (160, 1.0, 0.0), (400, 0.0, 2.0),
          (440, -0.4, 0.0), (520, 2.0, -0.3), (900, 0.0, 0.0)]


def _drive(csv_path: Path, seed: int = 1, script: list[tuple[int, float, float]] = SCRIPT,
           steps: int = 1000) -> SimWorld:
    config = SimConfig.from_section({"seed": seed, "metrics_csv": str(csv_path),
                                     "metrics_rate": 10.0})
    world = SimWorld(config, internal_scans=True)
    commands = dict((at, (v, w)) for at, v, w in script)
    for index in range(steps):
        if index in commands:
            world.command_twist(*commands[index])
        world.step()
    world.close()
    return world


def test_same_seed_and_commands_give_a_byte_identical_metrics_csv(tmp_path: Path) -> None:
    first = _drive(tmp_path / "a.csv")
    second = _drive(tmp_path / "b.csv")
    a, b = (tmp_path / "a.csv").read_bytes(), (tmp_path / "b.csv").read_bytes()
    assert a == b
    lines = a.decode().splitlines()
    assert lines[0] == ",".join(CSV_COLUMNS)
    assert len(lines) == 1 + 200  # 20 s at 10 rows/s
    assert lines[1].startswith("1,0.100000,")
    assert lines[-1].startswith("1,20.000000,")
    assert first.metrics_summary() == second.metrics_summary()


def test_other_commands_or_another_seed_change_the_csv(tmp_path: Path) -> None:
    base = _drive(tmp_path / "base.csv", steps=1000)
    changed = [*SCRIPT[:-1], (890, 0.0, 0.0)]
    _drive(tmp_path / "changed.csv", script=changed)
    assert (tmp_path / "base.csv").read_bytes() != (tmp_path / "changed.csv").read_bytes()
    other = _drive(tmp_path / "seed.csv", seed=2)
    assert other.world.circles != base.world.circles


def test_collision_course_shows_in_metrics(tmp_path: Path) -> None:
    world = _drive(tmp_path / "run.csv", script=[(0, 2.0, 0.0)], steps=600)
    summary = world.metrics_summary()
    assert summary["collisions"] == 1
    assert summary["path_length_m"] == pytest.approx(8.0 - 0.2, abs=0.01)  # into the wall
    last = (tmp_path / "run.csv").read_text().splitlines()[-1].split(",")
    assert int(last[CSV_COLUMNS.index("collisions")]) == 1


def test_smoothness_is_rms_of_finite_differences() -> None:
    metrics = RunMetrics()
    for v in (1.0, 1.0, 1.0):  # from rest: a = 1, 0, 0 ; j = 1, -1, 0 (dt = 1)
        metrics.record(1.0, 0.0, 0.0, 0.0, v, 0.0, v, 0)
    metrics.record(1.0, 0.0, 0.0, 0.0, 1.0, 2.0, 1.0, 0)  # w: a = 2 ; j = 2
    summary = metrics.summary()
    assert summary["rms_linear_acceleration_m_s2"] == pytest.approx(math.sqrt(1 / 4))
    assert summary["rms_linear_jerk_m_s3"] == pytest.approx(math.sqrt(2 / 4))
    assert summary["rms_angular_acceleration_rad_s2"] == pytest.approx(math.sqrt(4 / 4))
    assert summary["rms_angular_jerk_rad_s3"] == pytest.approx(math.sqrt(4 / 4))
    assert summary["path_length_m"] == 4.0 and summary["elapsed_s"] == 4.0
    assert summary["mean_speed_m_s"] == 1.0 and summary["max_speed_m_s"] == 1.0


def test_reset_starts_a_new_run_in_the_same_file(tmp_path: Path) -> None:
    path = tmp_path / "runs.csv"
    metrics = RunMetrics(path, rate=2.0)
    for _ in range(4):
        metrics.record(0.25, 1.0, 2.0, 0.5, 0.4, 0.0, 0.1, 3)
    metrics.reset()
    assert metrics.summary()["run"] == 2 and metrics.summary()["collisions"] == 0
    for _ in range(2):
        metrics.record(0.25, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0)
    metrics.close()
    rows = path.read_text().splitlines()[1:]
    assert [row.split(",")[:2] for row in rows] == [["1", "0.500000"], ["1", "1.000000"],
                                                     ["2", "0.500000"]]
    # after 2 steps of 0.25 s at 0.4 m/s from rest: a = 1.6, 0 ; j = 6.4, -6.4
    assert rows[0] == "1,0.500000,1.000000,2.000000,0.500000,0.400000,0.000000,0.200000,3," \
                      "0.400000,1.131371,0.000000,6.400000,0.000000"


def test_rate_must_be_positive() -> None:
    with pytest.raises(ValueError, match="rate"):
        RunMetrics(rate=0.0)
