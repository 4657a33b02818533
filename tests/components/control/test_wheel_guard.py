# Measured wheel speeds in /api/status and the wheel-mismatch guard: it stops a miswired robot
# within its configured time, and never trips on a healthy one driving around.
from __future__ import annotations

import math
import random
import statistics
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from daemon.bus import Bus
from daemon.clock import VirtualClock
from daemon.commands import Twist
from daemon.components.control.loop import ControlLoop
from daemon.components.control.supervisor import StallSupervisor
from daemon.components.control.wheel_guard import GuardSettings, WheelGuard
from daemon.config import load_config
from daemon.latency import LatencyTracker
from drivers import EncoderReading
from drivers.mock import MockDriver
from tests.support.compare import close_to
from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.wait import wait_for

TIME_S = 0.5


def readings(speeds: tuple[float, float], seconds: float,
             rate: float = 50.0) -> Iterator[tuple[float, EncoderReading]]:
    for step in range(round(seconds * rate) + 1):
        t = step / rate
        yield t, EncoderReading(speeds[0] * t, speeds[1] * t, t)


def test_a_wheel_turning_against_its_command_trips_after_the_configured_time() -> None:
    guard = WheelGuard(GuardSettings(time_s=TIME_S))
    trips = [(t, reason) for t, reading in readings((-4.0, 4.0), 2.0)
             if (reason := guard.update(reading, (4.0, 4.0), t))]
    assert len(trips) == 1, "a trip latches"
    t, reason = trips[0]
    assert TIME_S <= t <= TIME_S + 0.2  # the first measurement needs half a window
    assert reason.startswith("left wheel measured -4.00 rad/s while commanded +4.00")
    assert "against the command" in reason and guard.status() == {"left": -4.0, "right": 4.0}
    guard.reset()
    assert guard.tripped is None and guard.status() is None


@pytest.mark.parametrize("speeds, likely", [((0.0, 4.0), "stalled"), ((4.0, 12.0), "too fast")])
def test_a_stall_and_a_runaway_trip_too(speeds: tuple[float, float], likely: str) -> None:
    guard = WheelGuard(GuardSettings(time_s=TIME_S))
    reasons = [r for t, reading in readings(speeds, 1.0) if (r := guard.update(reading,
                                                                                (4.0, 4.0), t))]
    assert len(reasons) == 1 and likely in reasons[0]


def test_a_wheel_within_tolerance_or_a_short_miss_never_trips() -> None:
    guard = WheelGuard(GuardSettings(time_s=TIME_S))
    assert not any(guard.update(r, (4.0, 4.0), t) for t, r in readings((3.0, 5.5), 3.0))
    short = WheelGuard(GuardSettings(time_s=TIME_S))
    for t, reading in readings((-4.0, 4.0), 0.4):
        assert short.update(reading, (4.0, 4.0), t) is None
    assert short.update(None, (4.0, 4.0), 0.5) is None  # a fault: measured afresh
    assert short.status() is None
    disabled = WheelGuard(GuardSettings(time_s=0.0))
    assert not any(disabled.update(r, (4.0, 4.0), t) for t, r in readings((-4.0, 4.0), 2.0))


def test_a_wheel_turning_while_every_command_was_zero_trips() -> None:
    """At rest (zero written for longer than lag_s) the guard takes a shortcut while both
    wheels measure still; a wheel turning under a zero command still trips it."""
    guard = WheelGuard(GuardSettings(time_s=TIME_S))
    assert not any(guard.update(r, (0.0, 0.0), t) for t, r in readings((0.0, 1.0), 2.0))
    runaway = WheelGuard(GuardSettings(time_s=TIME_S))
    reasons = [(t, r) for t, reading in readings((0.0, 3.0), 2.0)
               if (r := runaway.update(reading, (0.0, 0.0), t))]
    assert len(reasons) == 1 and TIME_S <= reasons[0][0] <= TIME_S + 0.2
    assert reasons[0][1].startswith("right wheel measured +3.00 rad/s while commanded +0.00")


def test_the_shortcut_at_rest_judges_like_the_full_check() -> None:
    """Zero commands after driving: the full check runs until every command of the last lag_s
    was zero, and a wheel that keeps turning after that trips as it did before."""
    settings = GuardSettings(time_s=TIME_S)
    guard = WheelGuard(settings)
    for t, reading in readings((4.0, 4.0), 1.0):
        assert guard.update(reading, (4.0, 4.0), t) is None
    tripped = []
    for step in range(1, 101):  # commanded zero from t = 1 s, the left wheel keeps turning
        t = 1.0 + step / 50.0
        reading = EncoderReading(4.0 * t, 4.0, t)
        if (reason := guard.update(reading, (0.0, 0.0), t)) is not None:
            tripped.append((t, reason))
    assert len(tripped) == 1 and tripped[0][1].startswith("left wheel")
    assert 1.0 + settings.lag_s <= tripped[0][0] <= 1.0 + settings.lag_s + TIME_S + 0.1


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([0.0, 0.0, 0.0, 1.5, -2.0]),
                          st.sampled_from([0.0, 0.0, 1.5]),
                          st.floats(0.001, 0.2)), min_size=1, max_size=60))
def test_equal_writes_kept_once_give_the_window_every_write_gives(
        writes: list[tuple[float, float, float]]) -> None:
    """The guard keeps one entry for a run of equal writes (an idle robot writes zero every
    tick); the lowest and highest speed written during the last lag_s stay what they would be
    with every write kept."""
    guard = WheelGuard(GuardSettings(time_s=TIME_S))
    lag, t, every = guard.settings.lag_s, 0.0, []
    for left, right, dt in writes:
        t += dt
        guard._remember((left, right), t)
        every.append((t, left, right))
        recent = [w for w in every if t - w[0] <= lag]
        for index in (0, 1):
            kept = guard._wheels[index]
            assert (min(kept), max(kept)) == (min(w[1 + index] for w in recent),
                                              max(w[1 + index] for w in recent))


# -- in the simulated robot ------------------------------------------------------------------


def status(daemon: DaemonSubprocess) -> dict[str, Any]:
    code, body = daemon.get("/api/status")
    assert code == 200, body
    return body  # type: ignore[no-any-return]


def sim_daemon(tmp_path: Path, driver: str, miswire: list[str]) -> DaemonSubprocess:
    toml = (f'[sim]\ndriver = "{driver}"\nmiswire = {miswire!r}\nlidar = false\n'
            f'[control]\nwheel_mismatch_time_s = {TIME_S}\n').replace("'", '"')
    return DaemonSubprocess(tmp_path, toml, args=("--sim",), use_mock_log=False)


def refused(daemon: DaemonSubprocess, twist: dict[str, Any]) -> int | None:
    """Drive with ``twist``: the status of the refusal, or None when accepted."""
    code: int = daemon.post("/api/cmd_vel", twist)[0]
    return None if code == 200 else code


def test_the_guard_stops_a_robot_with_a_reversed_motor(tmp_path: Path) -> None:
    with sim_daemon(tmp_path, "pigpio", ["left_motor_reversed"]) as daemon:
        start = status(daemon)["ground_truth"]["theta"]
        code = wait_for(lambda: refused(daemon, {"linear": {"x": 0.2}}),
                        "the wheel guard to trip (a drive command refused)", interval_s=0.05)
        assert code == 409  # refused: the e-stop latched
        code, health = daemon.get("/api/health")
        control = health["components"]["control"]
        assert code == 503 and control["status"] == "error", health
        reason = control["wheel_guard"]["tripped"]
        assert reason.startswith("left wheel measured -") and "against the command" in reason
        assert status(daemon)["estop"]["engaged"]
        wait_for(lambda: close_to(status(daemon)["ground_truth"]["w"], 0.0, 1e-3),
                 "the robot to stop")
        # it spun in place (0.2 m/s per wheel, opposite ways) for about TIME_S, not longer
        turned = abs(status(daemon)["ground_truth"]["theta"] - start)
        assert turned < (0.4 / 0.30) * (TIME_S + 0.5), turned
        # the reset: release the e-stop; then only a fresh command moves the robot again
        assert daemon.post("/api/estop", {"engaged": False})[0] == 200
        assert daemon.get("/api/health")[0] == 200
        assert daemon.post("/api/cmd_vel", {"linear": {"x": 0.2}})[0] == 200


def command(daemon: DaemonSubprocess, v: float, w: float) -> None:
    """A command the daemon takes. A busy machine can stall the loop long enough for the
    emulated link to time out (a driver fault, 409 while it reconnects): the command is sent
    again until taken; a wheel guard trip fails the test."""
    def taken() -> bool:
        code, body = daemon.post("/api/cmd_vel", {"linear": {"x": v}, "angular": {"z": w}})
        assert code in (200, 409) and "wheel mismatch" not in str(body), (code, body)
        return code == 200

    wait_for(taken, "the command taken (409 until the driver is back)", within_s=30.0)


@pytest.mark.parametrize("driver", ["serial", "l298n"])
def test_no_false_trip_while_wandering(driver: str, tmp_path: Path) -> None:
    """Random drive: forward, reverse, turns, stops, into walls; measured speeds follow the
    command and the guard never trips."""
    rng = random.Random(7)
    with sim_daemon(tmp_path, driver, []) as daemon:
        for _ in range(16):
            v, w = rng.uniform(-0.4, 0.6), rng.uniform(-1.5, 1.5)
            if rng.random() < 0.2:
                v = w = 0.0
            for _ in range(10):
                command(daemon, v, w)
                time.sleep(0.05)
        samples = []
        for step in range(40):  # a steady arc: measured beside commanded
            command(daemon, 0.3, 0.5)
            time.sleep(0.05)
            if step >= 20:
                now = status(daemon)
                samples.append((now["wheel_speeds_rad_s"], now["measured_wheel_speeds_rad_s"]))
        code, health = daemon.get("/api/health")
        assert code == 200 and health["components"]["control"]["wheel_guard"]["trips"] == 0
    # single measurements jitter: the sim's encoder noise (odom_noise), and an emulator process
    # a loaded machine starved catching up in one step (6.1 rad/s for 4.5 once in CI); their
    # median agrees within 0.4 rad/s and 10 % (7.06 for 7.5 on a CI box at load ~4)
    # a stall stop on a loaded machine makes the guard measure afresh: no measurement for
    # half a window (null in the status), which is no speed to compare
    samples = [(c, m) for c, m in samples if m is not None]
    assert len(samples) >= 10, samples
    for side in ("left", "right"):
        commanded = statistics.median(c[side] for c, _ in samples)
        measured = statistics.median(m[side] for _, m in samples)
        assert close_to(measured, commanded, 0.4 + 0.1 * abs(commanded)), (side, samples)


class SlowMotors(MockDriver):
    """The mock driver with slow hobby motors: each wheel follows its command through a
    first-order lag (time constant ``tau``), read out as exact encoder positions, all in the
    test's virtual time; the emergency path sets the target to zero (the wheels coast)."""

    def __init__(self, clock: VirtualClock, tau: float = 0.25) -> None:
        super().__init__({}, max_wheel_speed=40.0)
        self.clock, self.tau = clock, tau
        self.speed, self.target, self.position = [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]
        self.t = clock()

    def advance(self) -> None:
        now = self.clock()
        dt, self.t = now - self.t, now
        decay = math.exp(-dt / self.tau)
        for i in (0, 1):
            v0, vt = self.speed[i], self.target[i]
            self.position[i] += vt * dt + (v0 - vt) * self.tau * (1 - decay)
            self.speed[i] = vt + (v0 - vt) * decay

    async def _apply(self, left_rad_s: float, right_rad_s: float) -> None:
        self.advance()
        self.target = [left_rad_s, right_rad_s]

    def _read_encoders(self) -> EncoderReading | None:
        self.advance()
        return EncoderReading(self.position[0], self.position[1], self.clock())

    def _emergency_zero(self) -> bool:
        self.advance()
        self.target = [0.0, 0.0]
        return True


async def test_stall_stops_under_a_flood_are_no_wheel_mismatch() -> None:
    """A flood stalls the loop again and again, longer than the supervisor's 0.2 s, with a
    tick in between; the supervisor zeroes the wheels each time and slow motors coast down.
    Before, the readings from before a stall still made up the measured speed after it (the
    turns made before the stop, over the whole stall) against a command of zero, and the
    stalls' own time counted as mismatch time: the guard tripped ("too fast: a runaway speed
    loop?"), latched the e-stop and health went to error. A stall stop is no miswiring: the
    guard starts afresh after one. (Virtual time: the ticks, the stalls and the supervisor's
    check are stepped by the test.)"""
    clock = VirtualClock()
    config = load_config(None, env={})
    driver = SlowMotors(clock)
    control = ControlLoop(config, driver, Bus(), LatencyTracker(), clock=clock)
    control.supervisor = StallSupervisor(driver, 0.2, clock=clock)
    await control.start(realtime=False)
    period = control.period_s

    async def tick() -> None:
        clock.advance(period)
        control.supervisor.beat()
        await control.tick(clock())

    for step in range(100):  # 2 s at 1 m/s: the wheels at 20 rad/s
        if step % 5 == 0:
            assert (await control.submit("teleop", Twist(1.0, 0.0), t_recv=clock())).accepted
        await tick()
    assert driver.speed[0] > 19.0
    for _ in range(3):
        clock.advance(0.2 + 1e-6)  # the loop is blocked ...
        control.supervisor.check()  # ... the supervisor zeroes the wheels ...
        clock.advance(0.3)  # ... and the stall goes on while they coast down
        await tick()
    assert control.supervisor.stall_stops == 3
    for _ in range(50):
        await tick()
    assert control.wheel_guard.tripped is None, control.wheel_guard.tripped
    assert not control.arbiter.estop_engaged
    assert control.health()["status"] == "ok", control.health()
    assert control.wheel_guard.restarts == 3
    assert (await control.submit("teleop", Twist(0.5, 0.0), t_recv=clock())).accepted
    await control.stop()
