# The control tick's metronomes: the kernel timer (timerfd) and the thread fallback behave alike.
from __future__ import annotations

import asyncio
import itertools
import sys
import time
from collections.abc import Awaitable, Callable

import pytest

from daemon.components.control.metronome import Metronome, TimerMetronome, _Timer, metronome

PERIOD_S = 0.01

Kind = type[Metronome] | type[TimerMetronome]


def make(kind: Kind, loop: asyncio.AbstractEventLoop) -> Metronome | TimerMetronome:
    if kind is TimerMetronome:
        return TimerMetronome(loop, PERIOD_S, _Timer.create())
    return Metronome(loop, PERIOD_S)


KINDS = [Metronome, pytest.param(TimerMetronome, marks=pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="timerfd is Linux only"))]


async def deadlines_from(ticker: Metronome | TimerMetronome, count: int,
                         on_tick: Callable[[float], Awaitable[None] | None] | None = None,
                         ) -> list[float]:
    """The first ``count`` deadlines ``ticker.run`` delivers (each also to ``on_tick``)."""
    seen: list[float] = []
    done = asyncio.get_running_loop().create_future()

    def record(deadline: float) -> Awaitable[None] | None:
        seen.append(deadline)
        if len(seen) == count and not done.done():
            done.set_result(None)
        return on_tick(deadline) if on_tick else None

    runner = asyncio.create_task(ticker.run(record))
    try:
        await done
    finally:
        runner.cancel()
    return seen


@pytest.mark.parametrize("kind", KINDS)
async def test_ticks_come_on_absolute_deadlines_one_period_apart(kind: Kind) -> None:
    ticker = make(kind, asyncio.get_running_loop())
    ticker.start()
    try:
        deadlines = await deadlines_from(ticker, 5)
    finally:
        ticker.stop()
    for earlier, later in itertools.pairwise(deadlines):
        assert later - earlier == pytest.approx(PERIOD_S * round((later - earlier) / PERIOD_S))
    assert all(deadline <= time.monotonic() for deadline in deadlines)


@pytest.mark.parametrize("kind", KINDS)
async def test_a_blocked_loop_gets_one_tick_and_the_rest_counted_missed(kind: Kind) -> None:
    ticker = make(kind, asyncio.get_running_loop())
    ticker.start()

    def block_once(deadline: float) -> None:
        if ticker.missed == 0:
            time.sleep(8 * PERIOD_S)  # the event loop blocked (a stall)

    try:
        first, late, after = await deadlines_from(ticker, 3, block_once)
        assert ticker.missed >= 4  # the deadlines that passed while blocked were not queued
        assert late - first >= 4 * PERIOD_S  # the tick after the stall is the latest deadline
        assert after > late
    finally:
        ticker.stop()


@pytest.mark.parametrize("kind", KINDS)
async def test_a_tick_that_waits_holds_the_next_one_back_and_never_overlaps(kind: Kind) -> None:
    """The part of a tick that waits runs on the metronome's task; deadlines that come
    meanwhile are not handed to the tick (one waits, the rest are missed), so ticks never run
    side by side, and a free tick is handled in the callback itself."""
    ticker = make(kind, asyncio.get_running_loop())
    ticker.start()
    running = 0
    overlaps = 0

    async def wait_a_while() -> None:
        nonlocal running
        await asyncio.sleep(3.5 * PERIOD_S)
        running -= 1

    def every_other_tick_waits(deadline: float) -> Awaitable[None] | None:
        nonlocal running, overlaps
        overlaps += running > 0
        running += 1
        if round(deadline / PERIOD_S) % 2:
            return wait_a_while()
        running -= 1
        return None

    try:
        deadlines = await deadlines_from(ticker, 12, every_other_tick_waits)
    finally:
        ticker.stop()
    assert overlaps == 0
    assert ticker.missed >= 2  # 3.5 periods of waiting: more deadlines than one came
    assert deadlines == sorted(deadlines)


async def test_linux_gets_the_kernel_timer() -> None:
    ticker = metronome(asyncio.get_running_loop(), PERIOD_S)
    assert isinstance(ticker, TimerMetronome) == sys.platform.startswith("linux")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="timerfd is Linux only")
async def test_housekeeping_wakes_with_a_tick() -> None:
    """next_at gives the first deadline on the tick grid at or after a time: a loop timer set
    for it has fired by the time that tick is taken (the kernel timer wakes the loop for both)."""
    loop = asyncio.get_running_loop()
    ticker = TimerMetronome(loop, PERIOD_S, _Timer.create())
    ticker.start()
    try:
        first, = await deadlines_from(ticker, 1)
        when = time.monotonic() + 2.5 * PERIOD_S
        due = ticker.next_at(when)
        assert when <= due < when + PERIOD_S
        assert (due - first) / PERIOD_S == pytest.approx(round((due - first) / PERIOD_S))
        woken = loop.create_future()
        loop.call_at(due, woken.set_result, None)
        timer_done_at_due: list[bool] = []

        def note(deadline: float) -> None:
            if deadline >= due - PERIOD_S / 2:
                timer_done_at_due.append(woken.done())

        deadlines = await deadlines_from(ticker, 8, note)
        assert any(d == pytest.approx(due) for d in deadlines) and timer_done_at_due
    finally:
        ticker.stop()
