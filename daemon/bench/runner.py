# Runs the registered benchmark suites and prints their figures as a table or JSON lines.
from __future__ import annotations

import importlib
import json
import platform
import sys
import time

from daemon.bench import SUITES, BenchResult


def run_suites(only: list[str] | None, *, quick: bool, as_json: bool) -> int:
    names = only or list(SUITES)
    unknown = [n for n in names if n not in SUITES]
    if unknown:
        print(f"arbiterd bench: unknown suite {unknown[0]!r}; suites: {', '.join(SUITES)}",
              file=sys.stderr)
        return 2
    if not as_json:
        print(f"arbiterd bench on {platform.machine()} {platform.python_implementation()} "
              f"{platform.python_version()}, {time.strftime('%Y-%m-%d %H:%M')}")
    results: list[BenchResult] = []
    for name in names:
        if not as_json:
            print(f"running {name} ...", file=sys.stderr, flush=True)
        suite = importlib.import_module(SUITES[name].module)
        for result in suite.run(quick):
            results.append(result)
            if as_json:
                print(json.dumps(result.as_dict()), flush=True)
    if not as_json:
        print(format_table(results))
        print(missed_summary(results, quick))
    return 0


def missed_summary(results: list[BenchResult], quick: bool = False) -> str:
    """What missed its target (each with its value and target), or that nothing did."""
    judged = [r for r in results if r.ok is not None]
    missed = [r for r in judged if not r.ok]
    rough = " (--quick: shorter runs, rougher figures)" if quick else ""
    if not missed:
        return f"targets: all {len(judged)} met{rough}"
    lines = [f"targets: {len(missed)} of {len(judged)} missed{rough}:"]
    lines += [f"  {r.suite}/{r.name}: {_fmt(r.value)} {r.unit}, target {r.target}"
              for r in missed]
    return "\n".join(lines)


def format_table(results: list[BenchResult]) -> str:
    rows = [("suite", "figure", "value", "unit", "target", "ok")]
    for r in results:
        ok = "" if r.ok is None else ("yes" if r.ok else "NO")
        rows.append((r.suite, r.name, _fmt(r.value), r.unit, r.target, ok))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip()
             for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    notes = [f"  {r.suite}/{r.name}: {r.note}" for r in results if r.note]
    return "\n".join(lines + (["notes:", *notes] if notes else []))


def _fmt(value: float) -> str:
    if value == 0 or 0.001 <= abs(value) < 1e6:
        return f"{value:.4g}" if abs(value) < 1000 else f"{value:,.0f}"
    return f"{value:.3e}"
