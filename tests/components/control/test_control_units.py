# Control building blocks: command parsing, arbiter, limiter, kinematics, odometry.
from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from daemon.commands import CommandError, Twist, parse_twist
from daemon.components.control.arbiter import Arbiter
from daemon.components.control.kinematics import DiffDrive, scale_to_limit
from daemon.components.control.limiter import AxisLimiter, AxisLimits
from daemon.components.control.odometry import Odometry
from daemon.components.control.supervisor import RETRY_S, StallSupervisor

LIMITS = AxisLimits(max_velocity=2.0, max_acceleration=1.0, max_deceleration=2.0,
                    emergency_deceleration=4.0)


def test_parse_twist_absent_fields_are_zero() -> None:
    assert parse_twist({}) == Twist(0.0, 0.0)
    assert parse_twist({"linear": {"x": 1}, "angular": {"z": -0.5}}) == Twist(1.0, -0.5)


@pytest.mark.parametrize(("body", "field"), [
    ({"linear": {"x": float("nan")}}, "linear.x: must be finite"),
    ({"angular": {"z": float("-inf")}}, "angular.z: must be finite"),
    ({"angular": {"z": "1"}}, "angular.z: expected a number"),
    ({"angular": {"x": 0.1}}, "angular.x: a differential-drive base"),
    ({"linear": {"x": 1}, "extra": 1}, "extra: unknown field"),
])
def test_parse_twist_refuses_with_field(body: dict[str, object], field: str) -> None:
    with pytest.raises(CommandError, match=field):
        parse_twist(body)


def test_limiter_accelerates_and_decelerates_at_their_own_rates() -> None:
    limiter = AxisLimiter(LIMITS)
    for _ in range(10):
        limiter.step(1.0, 0.02)
    assert limiter.velocity == pytest.approx(0.2)  # 1 m/s² for 0.2 s
    limiter.step(0.0, 0.02)
    assert limiter.velocity == pytest.approx(0.16)  # 2 m/s² deceleration
    limiter.step(0.0, 0.02, emergency=True)
    assert limiter.velocity == pytest.approx(0.08)  # 4 m/s² emergency


def test_limiter_reversal_counts_as_deceleration_first() -> None:
    limiter = AxisLimiter(LIMITS)
    limiter.velocity = 0.5
    limiter.step(-0.5, 0.1)
    assert limiter.velocity == pytest.approx(0.3)


def test_limiter_clamps_target_to_max_velocity() -> None:
    limiter = AxisLimiter(LIMITS)
    assert limiter.clamp_target(5.0) == (2.0, True)
    for _ in range(1000):
        limiter.step(5.0, 0.02)
    assert limiter.velocity == pytest.approx(2.0)


def test_jerk_limit_smooths_the_acceleration() -> None:
    limiter = AxisLimiter(AxisLimits(2.0, 1.0, 2.0, 4.0, max_jerk=5.0))
    limiter.step(1.0, 0.02)
    assert limiter.acceleration == pytest.approx(0.1)  # 5 m/s³ * 0.02 s
    limiter.step(1.0, 0.02)
    assert limiter.acceleration == pytest.approx(0.2)


@given(targets=st.lists(st.floats(-10, 10), min_size=1, max_size=60),
       dt=st.floats(0.001, 0.1), emergency=st.booleans())
def test_limiter_never_exceeds_its_limits(targets: list[float], dt: float,
                                          emergency: bool) -> None:
    limiter = AxisLimiter(LIMITS)
    for target in targets:
        before = limiter.velocity
        after = limiter.step(target, dt, emergency)
        assert abs(after) <= LIMITS.max_velocity + 1e-9
        fastest = max(LIMITS.max_acceleration, LIMITS.max_deceleration,
                      LIMITS.emergency_deceleration)
        assert abs(after - before) <= fastest * dt + 1e-9
        clamped = max(-2.0, min(2.0, target))
        assert abs(after - clamped) <= abs(before - clamped) + 1e-9  # always toward the target


def test_arbiter_priority_timeout_and_estop() -> None:
    arbiter = Arbiter(default_timeout_s=0.5)
    arbiter.submit("teleop", Twist(0.2, 0.0), now=0.0, priority=10)
    arbiter.submit("autonomy", Twist(0.5, 0.0), now=0.1, priority=5)
    assert arbiter.decide(0.2).source == "teleop"
    decision = arbiter.decide(0.55)  # teleop timed out, autonomy still live
    assert decision.source == "autonomy" and decision.twist.linear_x == 0.5
    decision = arbiter.decide(0.7)
    assert decision.source is None and decision.emergency and "deadman" in decision.reason
    arbiter.submit("teleop", Twist(0.1, 0.0), now=1.0)
    arbiter.engage_estop("test")
    assert arbiter.decide(1.1).emergency and arbiter.decide(1.1).twist == Twist()
    arbiter.release_estop()
    assert arbiter.decide(1.2).source is None  # the old command does not resume
    arbiter.submit("teleop", Twist(0.1, 0.0), now=1.3)
    assert arbiter.decide(1.3).source == "teleop"


def test_arbiter_dropped_owner_brakes_as_emergency() -> None:
    arbiter = Arbiter(default_timeout_s=0.5)
    arbiter.submit("ws:1", Twist(0.3, 0.0), now=0.0)
    assert arbiter.decide(0.1).source == "ws:1"
    arbiter.drop("ws:1")
    decision = arbiter.decide(0.1)
    assert decision.emergency and decision.twist == Twist()


def test_kinematics_round_trip_and_turn_in_place() -> None:
    drive = DiffDrive(wheel_separation=0.3, wheel_radius=0.05)
    left, right = drive.wheel_speeds(0.5, 0.0)
    assert left == right == pytest.approx(10.0)
    left, right = drive.wheel_speeds(0.0, 1.0)
    assert left == pytest.approx(-3.0) and right == pytest.approx(3.0)
    assert drive.body_twist(*drive.wheel_speeds(0.3, -0.7)) == pytest.approx((0.3, -0.7))
    assert drive.max_wheel_speed(2.0, 2.0) == pytest.approx(46.0)


def test_scale_to_limit_keeps_curvature() -> None:
    left, right, scaled = scale_to_limit(10.0, 20.0, 10.0)
    assert scaled and (left, right) == (5.0, 10.0)
    assert scale_to_limit(1.0, -2.0, 10.0) == (1.0, -2.0, False)


def test_odometry_from_encoders_square_path() -> None:
    drive = DiffDrive(wheel_separation=0.3, wheel_radius=0.05)
    odo = Odometry(drive)
    left = right = 0.0
    odo.update_from_encoders(left, right, 0.0)
    t = 0.0
    for _ in range(4):
        for _ in range(100):  # 1 m straight
            left += 0.2
            right += 0.2
            t += 0.01
            odo.update_from_encoders(left, right, t)
        quarter = (math.pi / 2) * 0.15 / 0.05  # wheel angle for a 90° turn in place
        for _ in range(100):
            left -= quarter / 100
            right += quarter / 100
            t += 0.01
            odo.update_from_encoders(left, right, t)
    assert odo.x == pytest.approx(0.0, abs=1e-9) and odo.y == pytest.approx(0.0, abs=1e-9)
    assert odo.theta == pytest.approx(0.0, abs=1e-9)


def test_odometry_open_loop_arc() -> None:
    odo = Odometry(DiffDrive(0.3, 0.05))
    for _ in range(1000):
        odo.update_open_loop(math.pi / 10, math.pi / 10, 0.01)  # half circle of radius 1 in 10 s
    assert odo.x == pytest.approx(0.0, abs=1e-6) and odo.y == pytest.approx(2.0, abs=1e-6)


# -- stall supervisor (its decisions, on a fake clock; the thread is in test_stall_supervisor) --


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class StubDriver:
    """Answers ``emergency_stop()`` from a script (True = the hardware took it)."""

    def __init__(self, *answers: bool) -> None:
        self.answers = list(answers)
        self.calls = 0
        self.last_emergency_error = "no reply from pigpiod (timed out)"
        self.last_command = (1.0, 1.0)  # the wheels turn: the supervisor's thread watches

    def emergency_stop(self) -> bool:
        self.calls += 1
        return self.answers.pop(0) if self.answers else True


def supervisor(driver: StubDriver, stall_stop_s: float = 0.2) -> tuple[StallSupervisor,
                                                                        FakeClock]:
    clock = FakeClock()
    return StallSupervisor(driver, stall_stop_s, clock=clock), clock  # type: ignore[arg-type]


def test_supervisor_waits_for_the_configured_time() -> None:
    driver = StubDriver()
    sup, clock = supervisor(driver)
    clock.now += 0.15
    sup.beat()
    clock.now += 0.19
    assert sup.check() == pytest.approx(0.01)  # next check due when the stall would begin
    assert driver.calls == 0 and not sup.stalled() and not sup.take_stop()


def test_supervisor_stops_once_per_stall_and_latches_for_the_loop() -> None:
    driver = StubDriver()
    sup, clock = supervisor(driver)
    clock.now += 0.25
    sup.check()
    assert driver.calls == 1 and sup.stall_stops == 1 and sup.stalled()
    clock.now += 2.0
    sup.check()  # the same stall: the wheels are already zeroed
    assert driver.calls == 1
    assert sup.take_stop() and not sup.take_stop()  # the loop forgets its commands once
    sup.beat()  # the tick runs again
    assert sup.health()["longest_stall_ms"] == pytest.approx(2250.0)
    assert sup.health()["last_stall_ms"] == pytest.approx(250.0)
    clock.now += 0.3
    sup.check()  # a second stall
    assert driver.calls == 2 and sup.stall_stops == 2


def test_supervisor_retries_an_emergency_stop_that_failed(caplog: pytest.LogCaptureFixture) -> None:
    driver = StubDriver(False, False, True)
    sup, clock = supervisor(driver)
    clock.now += 0.3
    assert sup.check() == RETRY_S
    assert not sup.take_stop()  # nothing to forget yet: the wheels were not stopped
    clock.now += RETRY_S
    sup.check()
    clock.now += RETRY_S
    sup.check()
    assert driver.calls == 3 and sup.failed_stops == 2 and sup.stall_stops == 1
    assert sup.take_stop()
    failures = [r for r in caplog.records if "did not reach the driver" in r.getMessage()]
    assert len(failures) == 1 and "timed out" in failures[0].getMessage()  # logged once


def test_supervisor_health_reports_a_stall_in_progress() -> None:
    sup, clock = supervisor(StubDriver())
    assert sup.health()["stalled"] is False
    clock.now += 0.5
    health = sup.health()
    assert health["stalled"] is True and health["stall_stops"] == 0
    assert health["stall_stop_s"] == 0.2


def test_supervisor_disabled_warns_and_starts_no_thread(caplog: pytest.LogCaptureFixture) -> None:
    driver = StubDriver()
    sup, clock = supervisor(driver, stall_stop_s=0.0)
    sup.start()
    clock.now += 10.0
    assert not sup.stalled() and sup._thread is None
    sup.stop()
    assert "stall supervisor is DISABLED" in caplog.text


def test_supervisor_counts_from_the_first_tick_after_start() -> None:
    """The start-up before the first tick is no stall: nothing drives the wheels yet, and
    ``longest_stall_ms`` is the longest time between two ticks."""
    driver = StubDriver()
    sup, clock = supervisor(driver)
    sup.start()
    try:
        clock.now += 0.5  # components still starting
        assert sup.check() == pytest.approx(0.2) and driver.calls == 0 and not sup.stalled()
        sup.beat()  # the first tick
        clock.now += 0.02
        sup.beat()
        assert sup.health()["longest_stall_ms"] == pytest.approx(20.0)
        clock.now += 0.25
        sup.check()  # a stall after the first tick is one
        assert driver.calls == 1 and sup.stalled()
    finally:
        sup.stop()


@given(st.lists(st.tuples(st.sampled_from([0.0, -0.0, 0.2, 0.2, 0.2, -0.3, 1.5]),
                          st.sampled_from([0.02, 0.02, 0.013, 0.5]), st.booleans()),
                max_size=60),
       st.sampled_from([0.0, 5.0]))
def test_the_held_speed_shortcut_steps_as_the_arithmetic(steps: list[tuple[float, float, bool]],
                                                         jerk: float) -> None:
    limits = AxisLimits(1.0, 2.0, 3.0, 6.0, jerk)
    fast, full = AxisLimiter(limits), AxisLimiter(limits)
    for target, dt, emergency in steps:
        got = fast.step(target, dt, emergency)
        want = full.limited_step(target, dt, emergency)
        assert (got, math.copysign(1, got)) == (want, math.copysign(1, want))
        assert (fast.velocity, fast.acceleration) == (full.velocity, full.acceleration)
