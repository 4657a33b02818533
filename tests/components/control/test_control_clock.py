# The control loop's clock seam, its guard hook and internal sources, stepped in virtual time.
from __future__ import annotations

import math
from collections.abc import AsyncIterator

import pytest

from daemon.bus import Bus
from daemon.clock import VirtualClock
from daemon.commands import Twist
from daemon.components.control.limiter import AxisLimiter, AxisLimits
from daemon.components.control.loop import ControlLoop
from daemon.config import build_driver, load_config
from daemon.latency import LatencyTracker
from daemon.motion_guard import Guarded
from drivers.mock import MockDriver


@pytest.fixture
async def loop() -> AsyncIterator[ControlLoop]:
    """A control loop on the mock driver whose clock only moves when the test says so."""
    config = load_config(None, env={})
    clock = VirtualClock()
    control = ControlLoop(config, build_driver(config, "mock"), Bus(), LatencyTracker(),
                          clock=clock)
    await control.start(realtime=False)
    yield control
    await control.stop()


async def run_ticks(control: ControlLoop, until: float, twist: Twist | None = None,
                    every_s: float = 0.1) -> None:
    """Tick to virtual time ``until``; with ``twist``, a teleop re-sends it every ``every_s``."""
    clock = control.clock
    assert isinstance(clock, VirtualClock)
    next_send = clock()
    while clock() + control.period_s <= until + 1e-9:
        if twist is not None and clock() + 1e-9 >= next_send:
            assert (await control.submit("teleop", twist, t_recv=clock())).accepted
            next_send += every_s
        clock.advance(control.period_s)
        await control.tick(clock())


def test_virtual_clock_moves_only_forward() -> None:
    clock = VirtualClock()
    clock.advance(0.25)
    clock.set(1.0)
    assert clock() == 1.0
    with pytest.raises(ValueError, match="cannot go back"):
        clock.set(0.5)


async def test_deadman_fires_in_virtual_time(loop: ControlLoop) -> None:
    await run_ticks(loop, 1.0, Twist(0.4, 0.0))
    assert loop.linear.velocity == pytest.approx(0.4)
    # the last command went out at 0.9 s: live until 1.4 s (cmd_vel_timeout 0.5 s)
    await run_ticks(loop, 1.4)
    assert loop.decision.source == "teleop"
    await run_ticks(loop, 1.44)
    assert loop.decision.reason.startswith("deadman") and loop.decision.emergency
    await run_ticks(loop, 1.6)  # 0.4 m/s at the emergency 4 m/s²: still after 0.1 s
    assert loop.linear.velocity == 0.0
    assert loop.wheels == (0.0, 0.0)


async def test_tick_sources_run_before_the_step_and_commands_are_announced(
        loop: ControlLoop) -> None:
    seen: list[str] = []

    def source(now: float) -> None:
        loop.arbiter.submit("internal", Twist(0.2, 0.0), now, priority=0)

    loop.tick_sources.add(source)
    loop.on_command.add(seen.append)
    await run_ticks(loop, 0.02)
    assert loop.decision.source == "internal"  # applied in the same tick
    await loop.submit("teleop", Twist(0.1, 0.0), t_recv=loop.clock())
    assert seen == ["teleop"]
    assert loop.decision.source == "teleop"  # the client outranks the internal source


class HalvingGuard:
    """A guard that halves every target and asks for the emergency deceleration."""

    def __init__(self) -> None:
        self.calls: list[tuple[float, float, float, float, float]] = []
        self.poses: list[tuple[float, float, float, float]] = []

    def limit(self, linear: float, angular: float, current_linear: float,
              current_angular: float, now: float) -> Guarded:
        self.calls.append((linear, angular, current_linear, current_angular, now))
        return Guarded(linear / 2, angular / 2, brake=True)

    def observe(self, now: float, x: float, y: float, theta: float) -> None:
        self.poses.append((now, x, y, theta))


async def test_guard_sits_between_arbiter_and_limiter(loop: ControlLoop) -> None:
    guard = HalvingGuard()
    loop.guard = guard
    await run_ticks(loop, 2.0, Twist(5.0, 0.0))
    assert guard.calls[-1][0] == 2.0  # the guard sees the target clamped to the limit
    assert loop.linear.velocity == pytest.approx(1.0)  # the guard's half
    assert len(guard.poses) == round(2.0 / loop.period_s)  # one pose per tick
    guard.calls.clear()
    loop.guard = None
    await loop.submit("teleop", Twist(2.0, 0.0), t_recv=loop.clock())
    assert guard.calls == []


async def test_guard_brake_uses_the_emergency_deceleration(loop: ControlLoop) -> None:
    await run_ticks(loop, 1.5, Twist(1.0, 0.0))
    assert loop.linear.velocity == pytest.approx(1.0)

    class StopGuard(HalvingGuard):
        def limit(self, linear: float, angular: float, current_linear: float,
                  current_angular: float, now: float) -> Guarded:
            return Guarded(0.0, 0.0, brake=True)

    loop.guard = StopGuard()
    await run_ticks(loop, loop.clock() + 0.1, Twist(1.0, 0.0))
    # emergency deceleration 4 m/s² for 0.1 s (the normal one would leave 0.8 m/s)
    assert loop.linear.velocity == pytest.approx(0.6, abs=1e-6)


def test_emergency_flag_never_speeds_up_faster_than_the_acceleration_limit() -> None:
    limiter = AxisLimiter(AxisLimits(2.0, 1.0, 2.0, 4.0))
    limiter.step(1.0, 0.1, emergency=True)
    assert limiter.velocity == pytest.approx(0.1)  # 1 m/s², not the 4 m/s² emergency
    limiter.step(0.0, 0.01, emergency=True)
    assert limiter.velocity == pytest.approx(0.06)  # slowing: 4 m/s²


async def test_odometry_is_published_at_the_configured_rate(loop: ControlLoop) -> None:
    """`[control] publish_rate` (20 Hz by default) of a 50 Hz tick: 20 samples a second,
    not one every second tick (25)."""
    from daemon.telemetry import ODOM
    samples: list[object] = []
    loop.bus.subscribe(ODOM, samples.append)
    await run_ticks(loop, 10.0)
    assert len(samples) == 200


def _zero_writes(control: ControlLoop) -> list[float]:
    driver = control.driver
    assert isinstance(driver, MockDriver)
    return [c.t_mono for c in driver.commands if c.left_rad_s == c.right_rad_s == 0.0]


async def test_at_rest_the_held_zero_is_written_again_every_rest_write_s(
        loop: ControlLoop) -> None:
    assert loop.rest_write_s == pytest.approx(0.1)  # [control] rest_write_s, the mock holds it
    driver = loop.driver
    assert isinstance(driver, MockDriver)
    await run_ticks(loop, 1.0)
    writes = len(driver.commands)
    assert 9 <= writes <= 11  # 1 s at rest: every 5th tick, not 50 writes
    await loop.submit("teleop", Twist(0.0, 0.0), t_recv=loop.clock())
    assert len(driver.commands) == writes + 1  # a command is written at once, even a zero
    await run_ticks(loop, 1.5, Twist(0.3, 0.0), every_s=0.02)
    moving = len(driver.commands)
    assert moving - writes >= 24  # moving: every tick and every command writes
    await run_ticks(loop, 3.0)  # the deadman brakes to rest, then every 0.1 s again
    assert loop.wheels == (0.0, 0.0)
    assert 10 <= len(driver.commands) - moving <= 40


async def test_a_fault_or_a_stall_stop_writes_the_zero_at_the_next_tick(loop: ControlLoop) -> None:
    await run_ticks(loop, 0.5)
    driver = loop.driver
    assert isinstance(driver, MockDriver)
    before = len(driver.commands)
    loop.supervisor.latched = True  # the supervisor zeroed the wheels behind the loop's back
    await run_ticks(loop, 0.52)
    assert len(driver.commands) == before + 1  # the next tick writes zero again


async def test_scheduled_callbacks_run_when_due_and_say_when_next(loop: ControlLoop) -> None:
    seen: list[float] = []

    def every_quarter(now: float) -> float:
        seen.append(now)
        return now + 0.25

    remove = loop.schedule.add(every_quarter)
    await run_ticks(loop, 1.0)
    assert [round(t, 2) for t in seen] == [0.02, 0.28, 0.54, 0.8]
    remove()
    await run_ticks(loop, 2.0)
    assert len(seen) == 4 and loop.schedule.next_due == math.inf


async def test_a_scheduled_callback_that_raises_is_tried_again_a_second_later(
        loop: ControlLoop, caplog: pytest.LogCaptureFixture) -> None:
    calls: list[float] = []

    def broken(now: float) -> float:
        calls.append(now)
        raise RuntimeError("broken report")

    loop.schedule.add(broken)
    await run_ticks(loop, 2.5)
    assert [round(t, 2) for t in calls] == [0.02, 1.02, 2.02]
    assert "control tick failed" in caplog.text
    assert loop.linear.velocity == 0.0  # the tick went on
