# Repeated log lines are throttled per source: a /goal_pose flood writes kilobytes, not megabytes.
from __future__ import annotations

import io
import logging
from collections.abc import Iterator
from pathlib import Path

import pytest

from daemon.cli import setup_logging
from daemon.logthrottle import RepeatFilter
from tests.support.in_process_daemon import in_process_daemon
from tests.support.rosbridge import connect
from tests.support.wait import eventually


def test_a_kind_of_line_passes_a_burst_per_window_then_says_how_many_were_left_out() -> None:
    now = [0.0]
    limiter = RepeatFilter(burst=3, window_s=10.0, clock=lambda: now[0])
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.addFilter(limiter)
    log = logging.getLogger("test.throttle")
    log.addHandler(handler)
    log.propagate = False
    try:
        for n in range(100):
            log.warning("goal %d refused", n)
        log.warning("another kind of line")
        now[0] = 10.0
        log.warning("goal %d refused", 100)
    finally:
        log.removeHandler(handler)
        log.propagate = True
    lines = stream.getvalue().splitlines()
    assert lines == ["goal 0 refused", "goal 1 refused", "goal 2 refused",
                     "another kind of line",
                     "goal 100 refused [97 more like this not logged in the last 10 s]"]


@pytest.fixture
def daemon_log() -> Iterator[tuple[io.StringIO, io.StringIO]]:
    """The daemon's log as the service writes it, and beside it (the in-run baseline) every
    line unthrottled."""
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    throttled, everything = io.StringIO(), io.StringIO()
    setup_logging("info", True, throttled, {})
    unthrottled = logging.StreamHandler(everything)
    unthrottled.setFormatter(root.handlers[0].formatter)
    root.addHandler(unthrottled)
    yield throttled, everything
    root.handlers[:] = handlers
    root.setLevel(level)


async def test_a_goal_flood_is_a_few_kilobytes_of_log(
        tmp_path: Path, daemon_log: tuple[io.StringIO, io.StringIO]) -> None:
    """Before: 1.73 MB in 11 s under a /goal_pose flood."""
    throttled, everything = daemon_log
    async with in_process_daemon(tmp_path, "[navigation]\nenabled = true\n") as robot:
        navigation = robot.component("navigation")
        async with connect(robot.ws_url) as client:
            await client.send(op="advertise", topic="/goal_pose",
                              type="geometry_msgs/msg/PoseStamped")
            for n in range(1500):
                await client.send(op="publish", topic="/goal_pose", msg={
                    "header": {"frame_id": "odom"},
                    "pose": {"position": {"x": 0.2 + (n % 7) * 0.01, "y": 0.0}}})
            await eventually(lambda: navigation.navigator.goals >= 1500, "the goals taken")
        await client.ws.close()
    throttled_kb, baseline_kb = len(throttled.getvalue()) / 1e3, len(everything.getvalue()) / 1e3
    print(f"log under a flood of 1500 goals: {throttled_kb:.1f} kB (unthrottled in the same "
          f"run: {baseline_kb:.1f} kB)")
    assert throttled_kb < 30 and baseline_kb > 5 * throttled_kb
