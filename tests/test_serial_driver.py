# The serial (ROSArduinoBridge) driver against the emulated Arduino on a pseudo-terminal.
from __future__ import annotations

import asyncio
import math
import sys
import time
from collections.abc import AsyncIterator, Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import pytest

from drivers import rosarduino
from drivers.arduino_serial import SerialBridgeDriver
from drivers.base import DriverClosed, DriverFault, EncoderReading
from sim.arduino_emulator import ArduinoEmulator, Firmware
from sim.motor_model import MotorPair, WheelMotor
from tests.support.async_daemon_subprocess import (
    AsyncDaemonSubprocess,
    async_daemon_subprocess,
    driver_daemon_config,
)
from tests.support.net import free_port
from tests.support.paths import REPO
from tests.support.rigs import Rig, wired_rig
from tests.support.wait import eventually

MAX_WHEEL_SPEED = 20.0
WHEEL_RADIUS = 0.05
WHEEL_SEPARATION = 0.30
serial_rig_at = partial(wired_rig, "serial")


def make_driver(rig: Rig, **overrides: Any) -> SerialBridgeDriver:
    return SerialBridgeDriver(rig.options | overrides, max_wheel_speed=MAX_WHEEL_SPEED)


def motion_commands(emulator: ArduinoEmulator, since: float) -> list[str]:
    """Non-zero motor commands the firmware ran after monotonic time ``since``."""
    return [c.text for c in emulator.firmware.history
            if c.t_mono > since and c.text[:1] in "mo" and c.text not in ("m 0 0", "o 0 0")]


@pytest.fixture
def serial_rig(tmp_path: Path) -> Iterator[Rig]:
    with serial_rig_at(tmp_path) as the_rig:
        yield the_rig


@pytest.fixture
async def driver(serial_rig: Rig) -> AsyncIterator[SerialBridgeDriver]:
    drv = make_driver(serial_rig)
    await drv.open()
    yield drv
    await drv.close()


# -- the wire protocol, driver side (pure) ------------------------------------------------------

def test_commands_are_cr_terminated_lines() -> None:
    assert rosarduino.encode_command("e") == b"e\r"
    assert rosarduino.encode_command("m", 10, -10) == b"m 10 -10\r"
    assert rosarduino.encode_pid(20, 12, 0, 50) == b"u 20:12:0:50\r"


def test_speed_conversions() -> None:
    # one revolution per second at 1440 counts/rev and 30 Hz is 48 ticks per frame
    assert rosarduino.rad_s_to_ticks(2 * math.pi, 1440, 30.0) == 48
    assert rosarduino.rad_s_to_ticks(-2 * math.pi, 1440, 30.0) == -48
    assert rosarduino.ticks_to_rad_s(48, 1440, 30.0) == pytest.approx(2 * math.pi)
    assert rosarduino.rad_s_to_pwm(5.0, 10.0, 255) == 128
    assert rosarduino.rad_s_to_pwm(-50.0, 10.0, 255) == -255


def test_replies_are_parsed_strictly() -> None:
    assert rosarduino.parse_counts("120 -34") == (120, -34)
    assert rosarduino.parse_baud(" 57600") == 57600
    rosarduino.parse_ok("m", "OK")
    for bad in ("120", "1 2 3", "12 x", "Invalid Command", ""):
        with pytest.raises(rosarduino.ProtocolError, match="expected two integers"):
            rosarduino.parse_counts(bad)
    with pytest.raises(rosarduino.ProtocolError, match="'Invalid Command', expected 'OK'"):
        rosarduino.parse_ok("m", "Invalid Command")
    with pytest.raises(rosarduino.ProtocolError, match="non-printable"):
        rosarduino.decode_line(b"\x90\xfeKO\r")
    assert rosarduino.decode_line(b"OK\r") == "OK"


def test_line_splitter_reassembles_and_refuses_endless_lines() -> None:
    splitter = rosarduino.LineSplitter()
    assert splitter.feed(b"12 ") == []
    assert splitter.feed(b"34\r\nOK\r\nO") == [b"12 34\r", b"OK\r"]
    assert splitter.feed(b"K\r\n") == [b"OK\r"]
    with pytest.raises(rosarduino.ProtocolError, match="without a line end"):
        splitter.feed(b"x" * 100)


def test_counter_wrap_is_a_small_step() -> None:
    assert rosarduino.count_delta(-(2**31) + 5, 2**31 - 5) == 10
    assert rosarduino.count_delta(100, 150) == -50
    assert rosarduino.wrap_long(2**31) == -(2**31) and rosarduino.wrap_long(-5) == -5


def test_bad_options_name_the_key() -> None:
    with pytest.raises(ValueError, match=r"\[driver.serial\] mode: must be one of"):
        SerialBridgeDriver({"mode": "fast"}, max_wheel_speed=1.0)
    with pytest.raises(ValueError, match=r"unknown option.*baud_rate"):
        SerialBridgeDriver({"baud_rate": 9600}, max_wheel_speed=1.0)
    with pytest.raises(ValueError, match="timeout_s"):
        SerialBridgeDriver({"timeout_s": 0}, max_wheel_speed=1.0)


# -- the firmware model (pure, fake clock) ------------------------------------------------------

class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def make_firmware() -> tuple[Firmware, FakeClock]:
    clock = FakeClock()
    motors = MotorPair(WheelMotor(counts_per_rev=1440), WheelMotor(counts_per_rev=1440),
                       clock=clock)
    return Firmware(motors, clock=clock), clock


def test_firmware_answers_each_command() -> None:
    fw, _ = make_firmware()
    assert fw.feed(b"b\r") == b"57600\r\n"
    assert fw.feed(b"e\r") == b"0 0\r\n"
    assert fw.feed(b"u 1:2:3:4\r") == b"OK\r\n"
    assert fw.gains == (1, 2, 3, 4)
    assert fw.feed(b"z\r") == b"Invalid Command\r\n"
    assert fw.feed(b"\r") == b"Invalid Command\r\n"
    assert fw.feed(b"m 4") == b""  # incomplete until CR
    assert fw.feed(b"8 -48\re\r") == b"OK\r\n0 0\r\n"


def test_firmware_speed_units_and_raw_pwm() -> None:
    fw, clock = make_firmware()
    fw.feed(b"m 48 -24\r")
    left, right = fw.motors.targets()
    assert left == pytest.approx(2 * math.pi) and right == pytest.approx(-math.pi)
    clock.now += 1.0
    counts = rosarduino.parse_counts(fw.feed(b"e\r").decode().strip())
    assert counts[0] == pytest.approx(1440, abs=80) and counts[1] == pytest.approx(-720, abs=40)
    fw.feed(b"o 255 -128\r")
    assert fw.mode == "pwm"
    max_speed = fw.motors.left.max_speed_rad_s
    assert fw.motors.targets() == pytest.approx((max_speed, -max_speed * 128 / 255))
    fw.feed(b"m 0 0\r")
    assert fw.motors.targets() == (0.0, 0.0) and fw.mode == "stopped"


def test_firmware_auto_stops_two_seconds_after_the_last_motor_command() -> None:
    fw, clock = make_firmware()
    fw.feed(b"m 30 30\r")
    clock.now += 1.5
    fw.feed(b"e\r")  # reading encoders does not count as a motor command
    fw.tick()
    assert fw.motors.targets() != (0.0, 0.0)
    clock.now += 0.6
    fw.tick()
    assert fw.motors.targets() == (0.0, 0.0) and fw.auto_stops == 1


def test_firmware_reset_zeroes_encoders_and_stops() -> None:
    fw, clock = make_firmware()
    fw.feed(b"m 30 30\r")
    clock.now += 0.5
    assert fw.feed(b"e\r") != b"0 0\r\n"
    fw.reset()
    assert fw.feed(b"e\r") == b"0 0\r\n" and fw.motors.targets() == (0.0, 0.0)


def test_firmware_garbage_switch() -> None:
    fw, _ = make_firmware()
    fw.garbage = True
    reply = fw.feed(b"m 1 1\r")
    assert reply.endswith(b"\r\n") and reply != b"OK\r\n"
    with pytest.raises(rosarduino.ProtocolError):
        rosarduino.parse_ok("m", rosarduino.decode_line(reply[:-1]))


# -- driver against the emulator on a pty -------------------------------------------------------

async def test_open_sends_gains_and_leaves_motors_stopped(serial_rig: Rig) -> None:
    emulator = serial_rig.emulator
    drv = make_driver(serial_rig, pid_p=7, pid_d=3, pid_i=1, pid_o=40)
    await drv.open()
    try:
        assert emulator.opens == 1 and emulator.firmware.gains == (7, 3, 1, 40)
        # the boot probe, the encoder baseline, the gains, the motors stopped
        assert [c.text for c in emulator.firmware.history][:4] == ["e", "e", "u 7:3:1:40",
                                                                   "m 0 0"]
        assert emulator.motors.targets() == (0.0, 0.0)
        assert drv.health()["status"] == "ok"
    finally:
        await drv.close()


@pytest.mark.parametrize(("left", "right"), [(6.0, 6.0), (-4.0, -4.0), (3.0, -3.0), (0.0, 0.0)],
                         ids=["forward", "reverse", "turn", "stop"])
async def test_wheel_speeds_reach_the_firmware(serial_rig: Rig, driver: SerialBridgeDriver,
                                               left: float, right: float) -> None:
    await driver.set_wheel_speeds(1.0, 1.0)
    await driver.set_wheel_speeds(left, right)
    observed = serial_rig.observed_targets()
    quantum = serial_rig.quantum_rad_s
    assert observed[0] == pytest.approx(left, abs=quantum / 2 + 1e-9)
    assert observed[1] == pytest.approx(right, abs=quantum / 2 + 1e-9)


async def test_open_loop_mode_writes_raw_pwm(serial_rig: Rig) -> None:
    emulator = serial_rig.emulator
    drv = make_driver(serial_rig, mode="open_loop", full_pwm_speed=10.0)
    await drv.open()
    try:
        await drv.set_wheel_speeds(5.0, -10.0)
        assert emulator.firmware.pwm == (128, -255) and emulator.firmware.mode == "pwm"
        await drv.stop()
        assert emulator.firmware.history[-1].text == "o 0 0"
    finally:
        await drv.close()


async def test_inverted_side_flips_command_and_encoder(serial_rig: Rig) -> None:
    emulator = serial_rig.emulator
    drv = make_driver(serial_rig, left_motor_inverted=True, left_encoder_inverted=True,
                      poll_rate=100.0)
    await drv.open()
    try:
        await drv.set_wheel_speeds(5.0, 5.0)
        target_left, target_right = emulator.motors.targets()
        assert target_left < 0 < target_right
        await eventually(lambda: emulator.motors.positions()[1] > 1.0, "wheels to turn")
        await drv.stop()
        reading = await fresh_reading(drv)
        assert reading.left_rad > 0.9 and reading.right_rad > 0.9
    finally:
        await drv.close()


async def test_held_speed_outlives_the_firmware_auto_stop(serial_rig: Rig) -> None:
    emulator = serial_rig.emulator
    emulator.firmware.auto_stop_s = 0.3
    drv = make_driver(serial_rig, keepalive_s=0.1)
    await drv.open()
    try:
        await drv.set_wheel_speeds(2.0, 2.0)
        start = time.monotonic()
        await eventually(lambda: drv.keepalives >= 8, "keep-alives")
        assert time.monotonic() - start > 0.3 * 2
        assert emulator.firmware.auto_stops == 0 and emulator.motors.targets()[0] > 0
    finally:
        await drv.close()
    # with no host sending anything, the firmware's own auto-stop takes over
    emulator.firmware.feed(b"m 20 20\r")
    await eventually(lambda: emulator.firmware.auto_stops == 1, "auto-stop")
    assert emulator.motors.targets() == (0.0, 0.0)


async def test_a_robot_at_rest_sends_its_stop_once_per_keepalive_not_every_tick(
        serial_rig: Rig, driver: SerialBridgeDriver) -> None:
    """The board said OK to the stop: the same stop every tick is not written again until
    ``keepalive_s`` has passed (a serial round trip a tick cost the idle daemon ~1.4 % of a
    core); any other command, and the stop after it, go out at once."""
    firmware = serial_rig.emulator.firmware

    def stops() -> int:
        return sum(c.text == "m 0 0" for c in firmware.history)

    await driver.set_wheel_speeds(3.0, 3.0)
    await driver.set_wheel_speeds(0.0, 0.0)
    sent = stops()
    for _ in range(20):
        await driver.set_wheel_speeds(0.0, 0.0)
    assert stops() == sent and driver.writes >= 22
    driver._wire_sent_mono -= driver.settings.keepalive_s  # as if the keep-alive time passed
    await driver.set_wheel_speeds(0.0, 0.0)
    assert stops() == sent + 1
    await driver.set_wheel_speeds(1.0, 1.0)
    await driver.set_wheel_speeds(0.0, 0.0)
    assert stops() == sent + 2 and serial_rig.emulator.motors.targets() == (0.0, 0.0)


async def test_open_waits_for_the_board_reset(serial_rig: Rig) -> None:
    emulator = serial_rig.emulator
    emulator.boot_s = 0.3
    impatient = make_driver(serial_rig, reset_wait_s=0.0, boot_timeout_s=0.0, timeout_s=0.1)
    with pytest.raises(DriverFault, match=r"no reply to 'e' .* needs a larger "
                                          r"\[driver.serial\] reset_wait_s \(now 0\)"):
        await impatient.open()
    assert emulator.bytes_dropped > 0
    patient = make_driver(serial_rig, reset_wait_s=0.6)
    await patient.open()
    assert patient.health()["status"] == "ok"
    await patient.close()
    asking = make_driver(serial_rig, reset_wait_s=0.0, boot_timeout_s=2.0, timeout_s=0.1)
    await asking.open()  # it asks again until the bootloader is done
    assert asking.health()["status"] == "ok"
    await asking.close()


async def test_missing_port_is_a_fault_naming_it(tmp_path: Path) -> None:
    drv = SerialBridgeDriver({"port": str(tmp_path / "nothing"), "reset_wait_s": 0.0},
                             max_wheel_speed=MAX_WHEEL_SPEED)
    with pytest.raises(DriverFault, match=r"cannot open serial port .*nothing"):
        await drv.open()


async def test_close_then_open_reconnects_and_closed_driver_refuses(
        serial_rig: Rig, driver: SerialBridgeDriver) -> None:
    await driver.set_wheel_speeds(3.0, 3.0)
    await driver.close()
    assert serial_rig.motors.targets() == (0.0, 0.0)
    with pytest.raises(DriverClosed):
        await driver.set_wheel_speeds(1.0, 1.0)
    await driver.open()
    await driver.set_wheel_speeds(1.0, 1.0)
    assert serial_rig.motors.targets()[0] > 0
    assert serial_rig.emulator.opens == 2


async def test_safe_stop_zeroes_motors_from_a_fresh_driver(serial_rig: Rig) -> None:
    # a board that does not reset on open (e.g. a Leonardo): the stop must come from the driver
    emulator = serial_rig.emulator
    emulator.reset_on_open = False
    emulator.firmware.feed(b"m 40 40\r")
    assert emulator.motors.targets()[0] > 0
    await make_driver(serial_rig).safe_stop()
    assert emulator.motors.targets() == (0.0, 0.0)
    assert emulator.firmware.history[-1].text == "m 0 0"


# -- closed-loop odometry -------------------------------------------------------------------------

class PoseIntegrator:
    """Plain diff-drive dead reckoning from successive wheel positions (rad)."""

    def __init__(self) -> None:
        self.x = self.y = self.theta = 0.0
        self._last: tuple[float, float] | None = None

    def add(self, left_rad: float, right_rad: float) -> None:
        if self._last is not None:
            d_left = (left_rad - self._last[0]) * WHEEL_RADIUS
            d_right = (right_rad - self._last[1]) * WHEEL_RADIUS
            d_center, d_theta = (d_left + d_right) / 2, (d_right - d_left) / WHEEL_SEPARATION
            heading = self.theta + d_theta / 2
            self.x += d_center * math.cos(heading)
            self.y += d_center * math.sin(heading)
            self.theta += d_theta
        self._last = (left_rad, right_rad)


async def fresh_reading(drv: SerialBridgeDriver) -> EncoderReading:
    """An encoder reading taken after the wheels settled (two polls later)."""
    polls = drv.polls
    await eventually(lambda: drv.polls >= polls + 2, "encoder polls")
    reading = drv.read_encoders()
    assert reading is not None
    return reading


async def drive_until(drv: SerialBridgeDriver, motors: MotorPair, speeds: tuple[float, float],
                      done: Callable[[tuple[float, float]], bool],
                      tracks: tuple[PoseIntegrator, PoseIntegrator]) -> None:
    """Drive at ``speeds`` until ``done(true positions)``, stop, and let the wheels settle."""
    await drv.set_wheel_speeds(*speeds)
    odometry, truth = tracks

    async def sampled_until_done() -> bool:
        reading = drv.read_encoders()
        assert reading is not None
        odometry.add(reading.left_rad, reading.right_rad)
        truth.add(*motors.positions())
        return done(motors.positions())

    await eventually(sampled_until_done, "the wheels to cover the distance", interval_s=0.01)
    await drv.stop()
    await eventually(lambda: max(map(abs, motors.speeds())) < 1e-3, "wheels to stop")
    reading = await fresh_reading(drv)
    odometry.add(reading.left_rad, reading.right_rad)
    truth.add(*motors.positions())


async def test_odometry_of_one_metre_and_a_quarter_turn(tmp_path: Path) -> None:
    # the motors run 8x faster than real time: 1 m at 0.2 m/s takes 0.6 s
    motors = MotorPair(WheelMotor(counts_per_rev=1440), WheelMotor(counts_per_rev=1440),
                       clock=lambda: time.monotonic() * 8)
    with serial_rig_at(tmp_path, motors) as the_rig:
        drv = make_driver(the_rig, poll_rate=50.0)
        assert drv.settings.counts_per_rev == 1440  # the rig reads the resolution off the motors
        await drv.open()
        try:
            start = motors.positions()
            tracks = (PoseIntegrator(), PoseIntegrator())
            straight = 1.0 / WHEEL_RADIUS
            await drive_until(drv, motors, (4.0, 4.0),
                              lambda p: p[0] - start[0] >= straight, tracks)
            odometry, truth = tracks
            assert truth.x == pytest.approx(1.0, rel=0.1)
            assert math.hypot(odometry.x - truth.x, odometry.y - truth.y) <= 0.02 * truth.x
            turned = motors.positions()[1]
            quarter = (math.pi / 2) * (WHEEL_SEPARATION / 2) / WHEEL_RADIUS
            await drive_until(drv, motors, (-3.0, 3.0),
                              lambda p: p[1] - turned >= quarter, tracks)
        finally:
            await drv.close()
    assert math.degrees(truth.theta) == pytest.approx(90.0, abs=10.0)  # overshoot of the stop
    assert abs(math.degrees(odometry.theta - truth.theta)) <= 2.0
    assert math.hypot(odometry.x - truth.x, odometry.y - truth.y) <= 0.02 * math.hypot(truth.x,
                                                                                       truth.y)


# -- faults ---------------------------------------------------------------------------------------

async def test_port_vanishes_mid_drive_and_comes_back(serial_rig: Rig) -> None:
    emulator = serial_rig.emulator
    emulator.firmware.auto_stop_s = 0.3
    drv = make_driver(serial_rig)
    await drv.open()
    await drv.set_wheel_speeds(5.0, 5.0)
    await eventually(lambda: drv.polls > 3, "polls")
    before = drv.read_encoders()
    assert before is not None
    emulator.unplug()
    await eventually(lambda: drv.fault is not None, "fault")
    assert "vanished" in str(drv.fault) and drv.health()["status"] == "error"
    with pytest.raises(DriverFault):
        await drv.stop()
    # the port is gone, so the board's own auto-stop is what zeroes the motors
    await eventually(lambda: emulator.motors.targets() == (0.0, 0.0), "auto-stop")
    await drv.close()
    with pytest.raises(DriverFault, match="cannot open serial port"):
        await drv.open()
    emulator.replug()
    reopened_at = time.monotonic()
    await drv.open()
    assert drv.health()["status"] == "ok" and drv.fault is None
    after = await fresh_reading(drv)
    # positions continue from before the fault instead of jumping to the reset counter
    assert after.left_rad >= before.left_rad and after.left_rad - before.left_rad < 2.0
    await asyncio.sleep(drv.settings.keepalive_s * 2)
    assert motion_commands(emulator, reopened_at) == []
    assert emulator.motors.targets() == (0.0, 0.0)
    await drv.set_wheel_speeds(2.0, 2.0)
    assert emulator.motors.targets()[0] > 0
    await drv.close()


async def test_garbage_from_the_board_faults_and_recovers(serial_rig: Rig,
                                                          driver: SerialBridgeDriver) -> None:
    emulator = serial_rig.emulator
    await driver.set_wheel_speeds(5.0, 5.0)
    emulator.garbage = True
    await eventually(lambda: driver.fault is not None, "fault")
    assert "garbled" in str(driver.fault) and driver.health()["status"] == "error"
    with pytest.raises(DriverFault, match="faulted"):
        await driver.set_wheel_speeds(5.0, 5.0)
    with pytest.raises(DriverFault, match="faulted"):
        await driver.stop()
    # the stop still reached the firmware: only its replies are garbled
    await eventually(lambda: emulator.motors.targets() == (0.0, 0.0), "motors zeroed")
    await driver.close()
    emulator.garbage = False
    reopened_at = time.monotonic()
    await driver.open()
    reading = await fresh_reading(driver)
    assert all(math.isfinite(v) and abs(v) < 100 for v in (reading.left_rad, reading.right_rad))
    assert motion_commands(emulator, reopened_at) == []
    await driver.set_wheel_speeds(1.0, 1.0)
    assert emulator.motors.targets()[0] > 0


async def test_silent_board_is_a_read_timeout(serial_rig: Rig) -> None:
    emulator = serial_rig.emulator
    drv = make_driver(serial_rig, timeout_s=0.2)
    await drv.open()
    emulator.mute = True
    await eventually(lambda: drv.fault is not None, "fault")
    assert "no reply" in str(drv.fault)
    with pytest.raises(DriverFault):
        drv.read_encoders()
    await drv.close()
    emulator.mute = False
    await drv.open()
    assert drv.health()["status"] == "ok"
    await drv.close()


# -- end to end: the real daemon as a subprocess, the emulated Arduino in this process ------------

@pytest.fixture
async def daemon(serial_rig: Rig,
                 tmp_path: Path) -> AsyncIterator[tuple[AsyncDaemonSubprocess, ArduinoEmulator]]:
    emulator = serial_rig.emulator
    emulator.firmware.auto_stop_s = 1.0
    port = free_port()
    config = driver_daemon_config(tmp_path, "serial", serial_rig.options, port)
    async with async_daemon_subprocess(config, port, tmp_path / "daemon.log") as client:
        yield client, emulator
    assert emulator.motors.targets() == (0.0, 0.0)


async def drive_and_expect_motion(client: AsyncDaemonSubprocess, emulator: ArduinoEmulator) -> None:
    assert await client.cmd_vel(0.2) == 200
    await eventually(lambda: min(emulator.motors.targets()) > 0, "wheels to turn")


async def recover_and_stay_still(client: AsyncDaemonSubprocess, emulator: ArduinoEmulator,
                                 since: float) -> None:
    body = await client.wait_health("ok")
    assert body["components"]["control"]["reconnects"] >= 1
    await asyncio.sleep(0.5)  # several ticks and keep-alive periods
    assert motion_commands(emulator, since) == []
    assert emulator.motors.targets() == (0.0, 0.0)
    await drive_and_expect_motion(client, emulator)


async def test_daemon_survives_the_port_vanishing(
        daemon: tuple[AsyncDaemonSubprocess, ArduinoEmulator]) -> None:
    client, emulator = daemon
    await drive_and_expect_motion(client, emulator)
    emulator.unplug()
    body = await client.wait_health("error")
    assert "vanished" in str(body["components"]["control"]["fault"])
    await eventually(lambda: emulator.motors.targets() == (0.0, 0.0), "board auto-stop")
    assert await client.cmd_vel(0.2) == 409  # refused while faulted, not queued
    await asyncio.sleep(0.5)  # several failed reconnects with back-off
    assert client.process.returncode is None
    replugged = time.monotonic()
    emulator.replug()
    await recover_and_stay_still(client, emulator, replugged)


async def test_daemon_survives_garbage_from_the_board(
        daemon: tuple[AsyncDaemonSubprocess, ArduinoEmulator]) -> None:
    client, emulator = daemon
    await drive_and_expect_motion(client, emulator)
    emulator.garbage = True
    body = await client.wait_health("error")
    assert "garbled" in str(body["components"]["control"]["fault"])
    # the port still works, so the daemon's stop reached the motors
    await eventually(lambda: emulator.motors.targets() == (0.0, 0.0),
                     "motors zeroed by the daemon (before the board's auto-stop)", within_s=0.8)
    cleared = time.monotonic()
    emulator.garbage = False
    await recover_and_stay_still(client, emulator, cleared)


async def test_safe_stop_command_zeroes_the_motors(serial_rig: Rig, tmp_path: Path) -> None:
    emulator = serial_rig.emulator
    emulator.reset_on_open = False
    emulator.firmware.feed(b"m 40 40\r")
    config = driver_daemon_config(tmp_path, "serial", serial_rig.options, free_port())
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "daemon.cli", "safe-stop", "--config", str(config), cwd=REPO,
        stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
    _, stderr = await asyncio.wait_for(process.communicate(), 30)
    assert process.returncode == 0, stderr.decode()
    assert emulator.motors.targets() == (0.0, 0.0)
    assert emulator.firmware.history[-1].text == "m 0 0"


def test_bench_reports_command_latency_percentiles() -> None:
    from daemon.bench.driver_serial import run

    results = {r.name: r for r in run(quick=True)}
    assert all(r.suite == "drivers" and r.unit == "ms" for r in results.values())
    for stage in ("ack", "board"):
        p50 = results[f"serial command->{stage} p50"].value
        p99 = results[f"serial command->{stage} p99"].value
        assert math.isfinite(p50) and 0 < p50 <= p99
