# The pigpio driver against the pigpiod emulator: commands, encoders, odometry, faults.
from __future__ import annotations

import asyncio
import contextlib
import math
import re
import signal
import sys
import time
from collections.abc import AsyncIterator
from functools import partial
from pathlib import Path

import pigpio
import pytest
from hypothesis import given
from hypothesis import strategies as st

from daemon.bus import Bus
from daemon.components.control.loop import ControlLoop
from daemon.config import load_config
from daemon.latency import LatencyTracker
from drivers.base import DriverFault
from drivers.pigpio_pwm import PigpioDriver, speed_to_duty
from drivers.quadrature import QuadratureDecoder, quadrature_levels
from sim.pigpiod_emulator import CMD_HP, CMD_PROCU, CMD_PWM, CMD_WRITE
from sim.wiring import EMULATORS
from tests.support.async_daemon_subprocess import (
    AsyncDaemonSubprocess,
    async_daemon_subprocess,
    driver_daemon_config,
    reaped,
    terminate_cleanly,
)
from tests.support.compare import close_to
from tests.support.net import free_port
from tests.support.paths import REPO
from tests.support.rigs import FULL_DUTY_SPEED, Rig, restart_pigpiod_and_reopen, wired_rig
from tests.support.wait import eventually

pytestmark = pytest.mark.timeout(60)

WHEEL_RADIUS, WHEEL_SEPARATION = 0.05, 0.30
MAX_WHEEL_SPEED = 15.0
COUNTS_PER_REV = EMULATORS["pigpio"].counts_per_rev
EXACT = 1e-3
running_rig = partial(wired_rig, "pigpio")


def make_driver(the_rig: Rig, **overrides: object) -> PigpioDriver:
    return PigpioDriver(the_rig.options | overrides, max_wheel_speed=MAX_WHEEL_SPEED)


@contextlib.asynccontextmanager
async def opened(the_rig: Rig, **overrides: object) -> AsyncIterator[PigpioDriver]:
    """A driver on the rig, open for the block and closed after it."""
    driver = make_driver(the_rig, **overrides)
    await driver.open()
    try:
        yield driver
    finally:
        await driver.close()


# -- pure parts ------------------------------------------------------------------------------------


def test_speed_to_duty_maps_deadband_min_duty_and_saturation() -> None:
    assert speed_to_duty(0.0, 10.0, 0.2, 0.0) == 0.0
    assert speed_to_duty(0.4, 10.0, 0.2, 0.5) == 0.0  # inside the deadband
    assert speed_to_duty(5.0, 10.0, 0.0, 0.0) == pytest.approx(0.5)
    assert speed_to_duty(-5.0, 10.0, 0.2, 0.0) == pytest.approx(-0.6)  # 0.2 + 0.8 * 0.5
    assert speed_to_duty(30.0, 10.0, 0.2, 0.0) == 1.0


@given(st.lists(st.sampled_from([-1, 1]), max_size=200))
def test_quadrature_decoder_follows_any_walk(steps: list[int]) -> None:
    decoder, count = QuadratureDecoder(), 0
    decoder.reset_levels(*quadrature_levels(0))
    for step in steps:
        count += step
        decoder.update(*quadrature_levels(count))
    assert decoder.count == count
    assert decoder.errors == 0


def test_quadrature_decoder_counts_a_skipped_edge_as_an_error() -> None:
    decoder = QuadratureDecoder()
    decoder.reset_levels(*quadrature_levels(0))
    decoder.update(*quadrature_levels(2))  # both levels changed at once
    assert (decoder.count, decoder.errors) == (0, 1)


def test_pins_sharing_a_hardware_pwm_channel_are_refused() -> None:
    with pytest.raises(ValueError, match="left_pwm=12 and right_pwm=18"):
        PigpioDriver({"left_pwm": 12, "right_pwm": 18}, max_wheel_speed=10.0)
    with pytest.raises(ValueError, match=r"right_in1 = 23 is already used by left_in1"):
        PigpioDriver({"right_in1": 23}, max_wheel_speed=10.0)


# -- against the emulator --------------------------------------------------------------------------


@pytest.mark.parametrize("hardware_pwm", [True, False], ids=["hardware-pwm", "dma-pwm"])
async def test_forward_reverse_turn_stop_reach_the_bridges(hardware_pwm: bool,
                                                           tmp_path: Path) -> None:
    with running_rig(tmp_path, hardware_pwm=hardware_pwm) as the_rig:
        driver = make_driver(the_rig)
        await driver.open()
        try:
            for left, right in [(6.0, 6.0), (-4.0, -4.0), (-3.0, 3.0), (0.0, 0.0)]:
                await driver.set_wheel_speeds(left, right)
                assert close_to(the_rig.observed_targets(), (left, right), 0.02)
            assert (await driver.set_wheel_speeds(40.0, -40.0)) == (15.0, -15.0)  # clamped
            assert close_to(the_rig.observed_targets(), (15.0, -15.0), 0.02)
        finally:
            await driver.close()
        assert the_rig.observed_targets() == (0.0, 0.0)  # close() stopped the wheels
        pwm_cmds = {cmd for cmd, gpio, _ in the_rig.emulator.command_log() if gpio in (12, 13)}
        assert (CMD_HP in pwm_cmds) is hardware_pwm
        assert (CMD_PWM in pwm_cmds) is not hardware_pwm


async def test_per_side_inversion_matches_a_mirrored_motor(tmp_path: Path) -> None:
    with running_rig(tmp_path, left_motor_inverted=True) as the_rig:  # a mirrored left motor
        async with opened(the_rig) as driver:
            await driver.set_wheel_speeds(5.0, 5.0)
            assert close_to(the_rig.observed_targets(), (5.0, 5.0), 0.02)


async def test_unchanged_pins_are_not_rewritten(tmp_path: Path) -> None:
    with running_rig(tmp_path) as the_rig:
        driver = make_driver(the_rig, watch_interval=0.0)
        await driver.open()
        try:
            await driver.set_wheel_speeds(5.0, 5.0)
            before = len(the_rig.emulator.command_log())
            await driver.set_wheel_speeds(6.0, 5.0)
            sent = the_rig.emulator.command_log()[before:]
        finally:
            await driver.close()
        # the deadman script's feed (PROCU), then only the pin that changed
        assert [(cmd, gpio) for cmd, gpio, _ in sent] == [(CMD_PROCU, 0), (CMD_HP, 12)]


async def test_the_deadman_script_in_pigpiod_stops_an_unfed_robot(tmp_path: Path) -> None:
    """A daemon that stops writing (frozen, killed) leaves pigpiod's PWM running; the script
    the driver left in pigpiod zeroes the motor pins after deadman_s, and the next write after
    the gap sets every pin again."""
    with running_rig(tmp_path) as the_rig:
        driver = make_driver(the_rig, watch_interval=0.0, deadman_s=0.2)
        await driver.open()
        try:
            await driver.set_wheel_speeds(5.0, 5.0)
            assert close_to(the_rig.observed_targets(), (5.0, 5.0), 0.02)
            await eventually(lambda: the_rig.observed_targets() == (0.0, 0.0),
                             "the deadman script zeroing the pins")
            assert driver.deadman.trips(driver._pi) == 1
            await driver.set_wheel_speeds(5.0, 5.0)
            assert close_to(the_rig.observed_targets(), (5.0, 5.0), 0.02)
            assert driver.health()["deadman_s"] == 0.2
        finally:
            await driver.close()


async def test_a_robot_at_rest_keeps_the_deadman_fed(tmp_path: Path) -> None:
    """At rest the control loop writes the held zero only now and then ([control]
    rest_write_s), but at least four times per deadman period: the script never fires."""
    with running_rig(tmp_path) as the_rig:
        driver = make_driver(the_rig, watch_interval=0.0, deadman_s=0.2)
        assert driver.rest_hold_s() == pytest.approx(0.05)
        loop = ControlLoop(load_config(None, env={}), driver, Bus(), LatencyTracker())
        assert loop.rest_write_s == pytest.approx(0.05)
        await loop.start()
        try:
            start = loop.supervisor.clock()
            await eventually(lambda: loop.supervisor.clock() - start > 0.8, "0.8 s at rest",
                             interval_s=0.05)
            assert driver.deadman.trips(driver._pi) == 0
            assert 2 <= driver.writes < loop._ticks  # a write every 50 ms, not every tick
        finally:
            await loop.stop()


async def test_encoders_track_the_motors_in_both_directions(tmp_path: Path) -> None:
    with running_rig(tmp_path) as the_rig:
        driver = make_driver(the_rig)
        await driver.open()
        try:
            await driver.set_wheel_speeds(8.0, -8.0)
            await eventually(lambda: the_rig.motors.positions()[0] > 3.0, "the wheels to turn")
            await driver.stop()
            await settled(the_rig, driver)
            reading = driver.read_encoders()
            assert reading is not None
            left, right = the_rig.motors.positions()
            count_rad = 2 * math.pi / COUNTS_PER_REV
            assert abs(reading.left_rad - left) <= count_rad
            assert abs(reading.right_rad - right) <= count_rad
            assert reading.left_rad > 3.0 and reading.right_rad < -3.0
            assert driver.health()["encoder_errors"] == 0
        finally:
            await driver.close()


async def settled(the_rig: Rig, driver: PigpioDriver,
                  lost: tuple[int, int] = (0, 0)) -> None:
    """Wait until the wheels stopped and every emitted edge reached the driver.

    ``lost`` is how many edges each side missed earlier (while pigpiod was down).
    """
    await eventually(lambda: all(abs(v) < 1e-3 for v in the_rig.motors.speeds()),
                     "the wheels to stop")

    def delivered() -> bool:
        counts = tuple(d.count + gap for d, gap in zip(driver.decoders, lost, strict=True))
        return counts == the_rig.emulator.emitted_counts()

    await eventually(delivered, "every encoder edge to reach the driver")


# -- closed-loop odometry --------------------------------------------------------------------------


def integrate(pose: tuple[float, float, float], d_left: float, d_right: float) -> tuple[
        float, float, float]:
    """Diff-drive pose update for wheel rotations (rad) over one segment."""
    x, y, theta = pose
    ds = (d_left + d_right) / 2 * WHEEL_RADIUS
    d_theta = (d_right - d_left) * WHEEL_RADIUS / WHEEL_SEPARATION
    mid = theta + d_theta / 2
    return x + ds * math.cos(mid), y + ds * math.sin(mid), theta + d_theta


async def test_odometry_1m_straight_and_90_degree_turn_match_ground_truth(
        tmp_path: Path) -> None:
    fast = EMULATORS["pigpio"].motors(max_speed_rad_s=FULL_DUTY_SPEED,
                                      clock=lambda: 2.0 * time.monotonic())  # 2x real time
    with running_rig(tmp_path, fast) as the_rig:
        driver = make_driver(the_rig, deadman_s=0.0)  # no loop feeds it here
        await driver.open()
        try:
            truth, odom = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
            last_truth, last_odom = the_rig.motors.positions(), await wheel_positions(driver)
            straight = 1.0 / WHEEL_RADIUS  # wheel rad for 1 m
            turn = math.pi / 2 * WHEEL_SEPARATION / 2 / WHEEL_RADIUS  # wheel rad for 90 deg
            for left, right, distance in [(10.0, 10.0, straight), (-6.0, 6.0, turn)]:
                await drive(the_rig, driver, left, right, distance)
                now_truth, now_odom = the_rig.motors.positions(), await wheel_positions(driver)
                truth = integrate(truth, *(n - p for n, p in zip(now_truth, last_truth,
                                                                 strict=True)))
                odom = integrate(odom, *(n - p for n, p in zip(now_odom, last_odom, strict=True)))
                last_truth, last_odom = now_truth, now_odom
        finally:
            await driver.close()
    assert truth[0] == pytest.approx(1.0, abs=0.05)
    assert math.degrees(truth[2]) == pytest.approx(90.0, abs=5.0)
    assert math.hypot(odom[0] - truth[0], odom[1] - truth[1]) <= 0.02 * 1.0
    assert abs(math.degrees(odom[2] - truth[2])) <= 2.0


async def wheel_positions(driver: PigpioDriver) -> tuple[float, float]:
    reading = driver.read_encoders()
    assert reading is not None
    return reading.left_rad, reading.right_rad


async def drive(the_rig: Rig, driver: PigpioDriver, left: float, right: float,
                wheel_rad: float, lost: tuple[int, int] = (0, 0)) -> None:
    """Drive until the right wheel turned about ``wheel_rad`` more, then stop and settle."""
    start = the_rig.motors.positions()[1]
    coast = abs(right) * the_rig.motors.right.time_constant_s
    await driver.set_wheel_speeds(left, right)
    await eventually(lambda: abs(the_rig.motors.positions()[1] - start) >= wheel_rad - coast,
                     "the base to cover the distance", within_s=10.0)
    await driver.stop()
    await settled(the_rig, driver, lost)


# -- faults ----------------------------------------------------------------------------------------


async def test_pigpiod_unreachable_is_a_fault_naming_the_address(tmp_path: Path) -> None:
    with running_rig(tmp_path) as the_rig:
        port = the_rig.options["port"]
        the_rig.emulator.stop()
        driver = make_driver(the_rig)
        with pytest.raises(DriverFault, match=f"pigpiod unreachable at 127.0.0.1:{port}"):
            await driver.open()
        assert not driver.is_open


async def test_pigpiod_stops_and_restarts(tmp_path: Path) -> None:
    with running_rig(tmp_path) as the_rig:
        emulator = the_rig.emulator
        driver = make_driver(the_rig)
        await driver.open()
        try:
            await driver.set_wheel_speeds(8.0, 8.0)
            await eventually(lambda: the_rig.motors.positions()[0] > 2.0, "the wheels to turn")
            await settled_counts_nonzero(driver)
            emulator.stop()  # pigpiod exits: every socket drops, its PWM stops
            await eventually(lambda: driver.fault is not None, "the keep-alive to notice")
            assert "pigpiod at 127.0.0.1" in (driver.fault or "")
            assert driver.health()["status"] == "error"
            assert the_rig.observed_targets() == (0.0, 0.0)
            with pytest.raises(DriverFault):
                await driver.set_wheel_speeds(1.0, 1.0)
            before_outage = await wheel_positions(driver)

            await driver.close()  # the supervisor's reconnect: close, then open with back-off
            with pytest.raises(DriverFault, match="unreachable"):
                await driver.open()
            await restart_pigpiod_and_reopen(the_rig, driver)
            after = await wheel_positions(driver)
            assert after == before_outage  # totals kept across the reconnect, no jump

            emitted = the_rig.emulator.emitted_counts()
            lost = (emitted[0] - driver.decoders[0].count, emitted[1] - driver.decoders[1].count)
            assert all(gap > 0 for gap in lost)  # the coast while pigpiod was down went unseen
            start_truth = the_rig.motors.positions()
            await drive(the_rig, driver, 8.0, 8.0, 4.0, lost)
            moved_truth = the_rig.motors.positions()[0] - start_truth[0]
            moved_odom = (await wheel_positions(driver))[0] - after[0]
            assert moved_odom == pytest.approx(moved_truth, abs=2 * 2 * math.pi / COUNTS_PER_REV)
        finally:
            await driver.close()


async def settled_counts_nonzero(driver: PigpioDriver) -> None:
    await eventually(lambda: driver.decoders[0].count > 0, "encoder edges")


async def test_a_hung_pigpiod_times_out_into_a_fault(tmp_path: Path) -> None:
    with running_rig(tmp_path, timeout=0.2, watch_interval=0.0) as the_rig:
        async with opened(the_rig) as driver:
            await driver.set_wheel_speeds(5.0, 5.0)
            the_rig.emulator.unresponsive = True
            with pytest.raises(DriverFault, match="lost: write failed"):
                await driver.set_wheel_speeds(2.0, 2.0)
            assert driver.health()["status"] == "error"
            the_rig.emulator.unresponsive = False
            await driver.close()
            await driver.open()
            await driver.set_wheel_speeds(3.0, 3.0)
            assert close_to(the_rig.observed_targets(), (3.0, 3.0), 0.02)


async def test_safe_stop_from_a_fresh_process_zeroes_running_motors(tmp_path: Path) -> None:
    with running_rig(tmp_path) as the_rig:
        crashed = pigpio.pi("127.0.0.1", the_rig.options["port"], show_errors=False)
        crashed.write(23, 1)
        crashed.write(27, 1)
        crashed.hardware_PWM(12, 1000, 600_000)
        crashed.hardware_PWM(13, 1000, 600_000)
        crashed.stop()
        assert close_to(the_rig.observed_targets(), (12.0, 12.0), EXACT)
        await make_driver(the_rig).safe_stop()
        assert the_rig.observed_targets() == (0.0, 0.0)
        log = the_rig.emulator.command_log()
        assert (CMD_WRITE, 23, 0) in log and (CMD_WRITE, 27, 0) in log


# -- bench -----------------------------------------------------------------------------------------


def test_bench_reports_command_latency_percentiles() -> None:
    from daemon.bench.driver_pigpio import run

    results = {r.name: r for r in run(quick=True)}
    assert all(r.suite == "drivers" and r.unit == "ms" for r in results.values())
    for label in ("pigpio", "l298n (PiGPIOFactory)"):
        for stage in ("return", "pigpiod"):
            p50 = results[f"{label} command->{stage} p50"].value
            p99 = results[f"{label} command->{stage} p99"].value
            assert math.isfinite(p50) and 0 < p50 <= p99
    assert results["l298n (MockFactory) command->return p50"].value > 0


async def test_an_error_answer_is_a_fault_but_the_wheels_can_still_be_zeroed(
        tmp_path: Path) -> None:
    with running_rig(tmp_path) as the_rig:
        driver = make_driver(the_rig, pwm_range=100, hardware_pwm=False)
        await driver.open()
        try:
            await driver.set_wheel_speeds(5.0, 5.0)
            the_rig.emulator.bank.pins[12].pwm_range = 25  # someone else shrank the range
            with pytest.raises(DriverFault, match=r"pigpiod refused a write: .*dutycycle"):
                await driver.set_wheel_speeds(10.0, 10.0)
            assert driver.health()["status"] == "error"
            assert await driver.try_zero()
            assert the_rig.observed_targets() == (0.0, 0.0)
        finally:
            await driver.close()


# -- end to end: the real daemon as a subprocess, the pigpiod emulator in this process -------------


@pytest.fixture
async def daemon(tmp_path: Path) -> AsyncIterator[tuple[AsyncDaemonSubprocess, Rig]]:
    with running_rig(tmp_path) as the_rig:
        port = free_port()
        config = driver_daemon_config(tmp_path, "pigpio", the_rig.options, port)
        async with async_daemon_subprocess(config, port, tmp_path / "daemon.log") as client:
            yield client, the_rig
        assert the_rig.observed_targets() == (0.0, 0.0)


async def test_daemon_survives_pigpiod_stopping_and_restarting(
        daemon: tuple[AsyncDaemonSubprocess, Rig]) -> None:
    client, the_rig = daemon
    emulator = the_rig.emulator
    assert await client.cmd_vel(0.2) == 200
    await eventually(lambda: min(the_rig.observed_targets()) > 1.0, "the wheels to turn")

    emulator.stop()  # pigpiod exits
    body = await client.wait_health("error")
    assert "pigpiod at 127.0.0.1" in str(body["components"]["control"]["fault"])
    assert the_rig.observed_targets() == (0.0, 0.0)
    assert await client.cmd_vel(0.2) == 409  # refused while faulted, not queued
    await asyncio.sleep(0.5)  # several failed reconnects with back-off
    assert client.process.returncode is None

    emulator.start()  # pigpiod is back
    body = await client.wait_health("ok")
    assert body["components"]["control"]["reconnects"] >= 1
    deadline = time.monotonic() + 0.5  # several ticks: the wheels stay still
    while time.monotonic() < deadline:
        assert the_rig.observed_targets() == (0.0, 0.0)
        await asyncio.sleep(0.02)
    assert await client.cmd_vel(0.2) == 200  # a fresh command moves the robot again
    await eventually(lambda: min(the_rig.observed_targets()) > 1.0, "the wheels to turn again")


# -- standalone emulator in its own process ------------------------------------------------------


async def test_standalone_emulator_process_with_signal_switches() -> None:
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "sim.pigpiod_emulator", "--port", "0", cwd=REPO,
        stdout=asyncio.subprocess.PIPE)
    async with reaped(process):
        assert process.stdout is not None
        banner = (await asyncio.wait_for(process.stdout.readline(), 20)).decode()
        match = re.search(r"listening on ([\d.]+):(\d+)", banner)
        assert match, banner
        options = {"host": match.group(1), "port": int(match.group(2)), "encoders": True,
                   "max_wheel_speed": 20.0, "encoder_counts_per_rev": 240,
                   "watch_interval": 0.05}
        driver = PigpioDriver(options, max_wheel_speed=20.0)
        await driver.open()
        await driver.set_wheel_speeds(10.0, 10.0)
        await eventually(lambda: driver.decoders[0].count > 20, "encoder edges from the process")
        process.send_signal(signal.SIGUSR1)  # pigpiod stops
        await eventually(lambda: driver.fault is not None, "the lost pigpiod to be noticed")
        await driver.close()
        process.send_signal(signal.SIGUSR2)  # pigpiod restarts

        async def reopened() -> bool:
            with contextlib.suppress(DriverFault):
                await driver.open()
            return driver.is_open

        await eventually(reopened, "a reconnect after the restart", within_s=5.0,
                         interval_s=0.05)
        await driver.close()
        await terminate_cleanly(process)
