# The control tick's metronomes: the kernel timer (timerfd) and the thread fallback behave alike.
from __future__ import annotations

import asyncio
import itertools
import sys
import time

import pytest

from daemon.control.metronome import Metronome, TimerMetronome, _Timer, metronome

PERIOD_S = 0.01

Kind = type[Metronome] | type[TimerMetronome]


def make(kind: Kind, loop: asyncio.AbstractEventLoop) -> Metronome | TimerMetronome:
    if kind is TimerMetronome:
        return TimerMetronome(loop, PERIOD_S, _Timer.create())
    return Metronome(loop, PERIOD_S)


KINDS = [Metronome, pytest.param(TimerMetronome, marks=pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="timerfd is Linux only"))]


@pytest.mark.parametrize("kind", KINDS)
async def test_ticks_come_on_absolute_deadlines_one_period_apart(kind: Kind) -> None:
    ticker = make(kind, asyncio.get_running_loop())
    ticker.start()
    try:
        deadlines = [await ticker.wait() for _ in range(5)]
    finally:
        ticker.stop()
    for earlier, later in itertools.pairwise(deadlines):
        assert later - earlier == pytest.approx(PERIOD_S * round((later - earlier) / PERIOD_S))
    assert all(deadline <= time.monotonic() for deadline in deadlines)


@pytest.mark.parametrize("kind", KINDS)
async def test_a_blocked_loop_gets_one_tick_and_the_rest_counted_missed(kind: Kind) -> None:
    ticker = make(kind, asyncio.get_running_loop())
    ticker.start()
    try:
        await ticker.wait()
        time.sleep(8 * PERIOD_S)  # noqa: ASYNC251 - the event loop blocked (a stall)
        late = await ticker.wait()
        missed = ticker.missed
        assert missed >= 4  # the deadlines that passed while blocked were not queued
        after = await ticker.wait()
        assert after > late  # and the next tick is a fresh deadline, not a stale one
    finally:
        ticker.stop()


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
        first = await ticker.wait()
        when = time.monotonic() + 2.5 * PERIOD_S
        due = ticker.next_at(when)
        assert when <= due < when + PERIOD_S
        assert (due - first) / PERIOD_S == pytest.approx(round((due - first) / PERIOD_S))
        woken = loop.create_future()
        loop.call_at(due, woken.set_result, None)
        deadline = await ticker.wait()
        while deadline < due:
            deadline = await ticker.wait()
        assert deadline == pytest.approx(due) and woken.done()
    finally:
        ticker.stop()
