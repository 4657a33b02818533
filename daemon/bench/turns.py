# Tick lateness of one daemon in alternating turns of two conditions (off/on), and its figures.
from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass, field

from daemon.app import Daemon
from daemon.bench import BenchResult, percentile_ms

#: the lateness a feature may add to the tick's p99, against the same daemon without it (ms)
LATENESS_TARGET_MS = 0.5


async def tick_lateness(daemon: Daemon, seconds: float) -> list[float]:
    """The control tick's lateness (s) over the next ``seconds``."""
    latency = daemon.latency
    latency.tick_late_ms.clear()
    await asyncio.sleep(seconds)
    return [ms / 1e3 for ms in latency.tick_late_ms]


@dataclass
class Turns:
    """Lateness samples (s) of the off and on turns, and how the turns were cut."""
    seconds: float
    segment: float
    off: list[float] = field(default_factory=list)
    on: list[float] = field(default_factory=list)

    @property
    def schedule(self) -> str:
        return f"in turns of {self.segment:g} s over {2 * self.seconds:g} s, 50 Hz tick"


async def lateness_in_turns(daemon: Daemon, quick: bool,
                            switch: Callable[[bool], None]) -> Turns:
    """``switch(on)`` before each turn, then the tick's lateness over it."""
    turns = Turns(*((4.0, 1.0) if quick else (30.0, 5.0)))
    for i in range(max(2, round(2 * turns.seconds / turns.segment))):
        on = i % 2 == 1
        switch(on)
        (turns.on if on else turns.off).extend(await tick_lateness(daemon, turns.segment))
    return turns


def lateness_results(suite: str, turns: Turns, off: tuple[str, str], on: tuple[str, str],
                     baseline: str) -> list[BenchResult]:
    """The p99 of the off turns, and of the on turns against it plus the target; ``off`` and
    ``on`` are (figure, note), ``baseline`` names the off turns in the target."""
    p99_off, p99_on = percentile_ms(turns.off, 99), percentile_ms(turns.on, 99)
    added = p99_on - p99_off
    return [
        BenchResult(suite, off[0], round(p99_off, 4), "ms", note=off[1]),
        BenchResult(suite, on[0], round(p99_on, 4), "ms",
                    f"<= {baseline} + {LATENESS_TARGET_MS}", added <= LATENESS_TARGET_MS, on[1]),
    ]
