# Bench suite "navigation-tick": the control tick's lateness with a goal being planned and
# followed, beside the same daemon with navigation idle, in turns.
from __future__ import annotations

import asyncio
import tempfile
from pathlib import Path

from daemon.bench import BenchResult, bench_daemon, run_quietly
from daemon.bench.mapping_cost import publish_scans
from daemon.bench.turns import lateness_in_turns, lateness_results
from daemon.components.navigation.component import NavigationComponent
from daemon.components.navigation.messages import GoalRequest

SUITE = "navigation-tick"
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
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-") as tmp:
        async with bench_daemon(Path(tmp), serve_scan=True) as (daemon, _url):
            nav = next(c for c in daemon.components if isinstance(c, NavigationComponent))
            stop = asyncio.Event()
            scans = asyncio.create_task(publish_scans(daemon, stop))
            await asyncio.sleep(1.0)  # the first revolutions in the costmap
            goals = 0

            def switch(following: bool) -> None:
                nonlocal goals
                if following:
                    goals += _send_goal(nav)
                else:
                    nav.cancel("bench: idle turn")

            turns = await lateness_in_turns(daemon, quick, switch)
            nav.cancel("bench over")
            plans = nav.status().get("replans", 0)
            stop.set()
            await scans
    return lateness_results(
        SUITE, turns, baseline="idle",
        off=("tick lateness p99, navigation idle",
             "same daemon, 360-ray scans of the apartment on the bus at 10 Hz"),
        on=("tick lateness p99, navigation following a goal",
            f"{goals} goals 2 m away planned (planning process), followed and recovered from; "
            f"idle/following {turns.schedule}; replans in the last goal: {plans}"))


def run(quick: bool) -> list[BenchResult]:
    return run_quietly(_run(quick))
