# tests/support/wait.py: the one poll-until-true loop every test waits with.
from __future__ import annotations

import itertools
import time

import pytest

from tests.support.wait import Collector, Deadline, eventually, wait_for


def test_wait_for_returns_the_first_truthy_value() -> None:
    counter = itertools.count()
    assert wait_for(lambda: next(counter) >= 3 and "done", "three polls") == "done"


def test_wait_for_fails_naming_what_it_waited_for() -> None:
    start = time.monotonic()
    with pytest.raises(AssertionError, match=r"timed out after 0\.05 s waiting for the moon"):
        wait_for(lambda: False, "the moon", within_s=0.05)
    assert time.monotonic() - start < 1.0


def test_the_failure_can_describe_the_state_at_the_time_it_happens() -> None:
    readings = iter(range(1000))
    last = [0]

    def reading_above_1000() -> bool:
        last[0] = next(readings)
        return last[0] > 1000

    with pytest.raises(AssertionError, match=r"waiting for a reading > 1000; last \d+$"):
        wait_for(reading_above_1000, lambda: f"a reading > 1000; last {last[0]}", within_s=0.05)


def test_the_time_limit_is_named_never_positional() -> None:
    with pytest.raises(TypeError):
        wait_for(lambda: True, "x", 5)  # type: ignore[misc]


async def test_eventually_awaits_a_coroutine_condition_and_lets_the_loop_run() -> None:
    polls = []

    async def third_poll() -> int | None:
        polls.append(1)
        return len(polls) if len(polls) == 3 else None

    assert await eventually(third_poll, "the third poll") == 3
    with pytest.raises(AssertionError, match=r"timed out after 0\.05 s waiting for never"):
        await eventually(lambda: None, "never", within_s=0.05)


def test_a_collector_waits_for_items_handed_over() -> None:
    collect: Collector[int] = Collector()
    for item in range(3):
        collect(item)
    assert collect.wait(3, "three items") == [0, 1, 2] and collect.count() == 3
    with pytest.raises(AssertionError, match="waiting for a fourth"):
        collect.wait(4, "a fourth", within_s=0.05)


def test_a_deadline_counts_down_then_fails() -> None:
    """What a wait that cannot poll uses (a WebSocket read: see rosbridge.Client.expect)."""
    deadline = Deadline("the end", 0.05)
    assert 0.001 <= deadline.remaining() <= 0.05
    deadline.check()  # not yet
    time.sleep(0.06)
    assert deadline.remaining() == 0.001  # never 0, which often means "no timeout"
    with pytest.raises(AssertionError, match=r"timed out after 0\.05 s waiting for the end"):
        deadline.check()
