# Bench suite "navigation-tick": the control tick's lateness with a goal being planned and
# followed, beside the same daemon with navigation idle, in turns.
from __future__ import annotations

import asyncio
import tempfile
from pathlib import Path

from daemon.bench import BenchResult, bench_daemon, percentile_ms, run_quietly
from daemon.bench.mapping_cost import publish_scans, tick_lateness
from daemon.navigation.component import NavigationComponent
from daemon.navigation.messages import GoalRequest

SUITE = "navigation-tick"
LATENESS_TARGET_MS = 0.5
#: goals tried in turn, ahead, behind and to the sides of the start (odometry frame, m): the
#: first the costmap does not refuse is taken
GOALS = ((2.0, 0.0), (-2.0, 0.0), (0.0, 2.0), (0.0, -2.0), (1.5, 1.5), (-1.5, -1.5))


def _send_goal(nav: NavigationComponent) -> bool:
    """A goal 2 m away (the mock driver's robot never gets there: it keeps planning, following
    and recovering); False when every candidate was refused."""
    for x, y in GOALS:
        try:
            nav.request(GoalRequest(nav.frame, x, y))
        except ValueError:
            continue
        return True
    return False


async def _run(quick: bool) -> list[BenchResult]:
    seconds, segment = (4.0, 1.0) if quick else (30.0, 5.0)
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-") as tmp:
        async with bench_daemon(Path(tmp), serve_scan=True) as (daemon, _url):
            nav = next(c for c in daemon.components if isinstance(c, NavigationComponent))
            stop = asyncio.Event()
            scans = asyncio.create_task(publish_scans(daemon, stop))
            await asyncio.sleep(1.0)  # the first revolutions in the costmap
            idle: list[float] = []
            busy: list[float] = []
            goals = 0
            for i in range(max(2, round(2 * seconds / segment))):
                if i % 2 == 1:
                    goals += _send_goal(nav)
                else:
                    nav.cancel("bench: idle turn")
                (busy if i % 2 == 1 else idle).extend(await tick_lateness(daemon, segment))
            nav.cancel("bench over")
            plans = nav.status().get("replans", 0)
            stop.set()
            await scans
    p99_idle, p99_busy = percentile_ms(idle, 99), percentile_ms(busy, 99)
    added = p99_busy - p99_idle
    return [
        BenchResult(SUITE, "tick lateness p99, navigation idle", round(p99_idle, 4), "ms",
                    note="same daemon, 360-ray scans of the apartment on the bus at 10 Hz"),
        BenchResult(SUITE, "tick lateness p99, navigation following a goal", round(p99_busy, 4),
                    "ms", f"<= idle + {LATENESS_TARGET_MS}", added <= LATENESS_TARGET_MS,
                    f"{goals} goals 2 m away planned (planning process), followed and recovered "
                    f"from; idle/following in turns of {segment:g} s over {2 * seconds:g} s, "
                    f"50 Hz tick; replans in the last goal: {plans}"),
    ]


def run(quick: bool) -> list[BenchResult]:
    return run_quietly(_run(quick))
