# `arbiterd bench` as a user meets it: --help lists the suites, a run ends with what missed.
from __future__ import annotations

import sys
import types

import pytest

from daemon import bench
from daemon.bench import BenchResult, Suite, runner
from daemon.cli import main


def test_help_lists_every_suite_with_what_it_measures(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--help"]) == 0
    text = capsys.readouterr().out
    for name, suite in bench.SUITES.items():
        assert f"  {name} " in text and suite.what in text


def test_a_run_ends_with_what_missed_its_target(capsys: pytest.CaptureFixture[str],
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    fake = types.ModuleType("fake_bench_suite")
    fake.run = lambda quick: [  # type: ignore[attr-defined]
        BenchResult("fake", "ws_ratio", 1.64, "x", "<= 1.3x", False),
        BenchResult("fake", "tick_p99", 0.55, "ms", "<= 1 ms", True),
        BenchResult("fake", "rss", 41.0, "MB")]
    monkeypatch.setitem(sys.modules, "fake_bench_suite", fake)
    monkeypatch.setattr(runner, "SUITES", {"fake": Suite("fake_bench_suite", "a fake")})
    assert runner.run_suites(["fake"], quick=True, as_json=False) == 0
    out = capsys.readouterr().out
    assert out.endswith("targets: 1 of 2 missed (--quick: shorter runs, rougher figures):\n"
                        "  fake/ws_ratio: 1.64 x, target <= 1.3x\n")
    fake.run = lambda quick: [  # type: ignore[attr-defined]
        BenchResult("fake", "tick_p99", 0.55, "ms", "<= 1 ms", True)]
    assert runner.run_suites(["fake"], quick=False, as_json=False) == 0
    assert capsys.readouterr().out.endswith("targets: all 1 met\n")
