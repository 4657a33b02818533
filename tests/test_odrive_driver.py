# The odrive_can driver against the emulated ODrive: wire format, control, odometry and faults.
from __future__ import annotations

import asyncio
import itertools
import json
import math
import struct
import subprocess
import sys
import time
import uuid
from collections.abc import AsyncIterator, Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import can
import pytest

from base.options import Option
from drivers import cansimple
from drivers.base import DriverFault
from drivers.odrive_can import ODriveCanDriver
from sim.motor_model import MotorPair
from sim.odrive_emulator import ODriveEmulator
from tests.support.compare import close_to
from tests.support.paths import REPO
from tests.support.rigs import RIG_OPTIONS, Rig, wired_rig
from tests.support.wait import eventually, wait_for

WHEEL_RADIUS = 0.05
WHEEL_SEPARATION = 0.30
MAX_WHEEL_SPEED = 30.0
MULTICAST_GROUP = "239.74.163.2"
EXACT = 1e-4
LEFT_NODE = RIG_OPTIONS["odrive_can"]["left_node_id"]
RIGHT_NODE = RIG_OPTIONS["odrive_can"]["right_node_id"]
odrive_rig = partial(wired_rig, "odrive_can")


@pytest.fixture
def odrive(tmp_path: Path) -> Iterator[Rig]:
    with odrive_rig(tmp_path) as the_rig:
        yield the_rig


@pytest.fixture
async def make_driver(odrive: Rig) -> AsyncIterator[Callable[..., ODriveCanDriver]]:
    made: list[ODriveCanDriver] = []

    def make(**overrides: Any) -> ODriveCanDriver:
        driver = ODriveCanDriver(odrive.options | overrides, max_wheel_speed=MAX_WHEEL_SPEED)
        made.append(driver)
        return driver

    yield make
    for driver in made:
        await driver.close()


# -- wire format -------------------------------------------------------------------------------


def test_frame_ids_and_payloads_match_cansimple() -> None:
    assert cansimple.arbitration_id(3, cansimple.CMD_SET_INPUT_VEL) == 0x6D
    assert cansimple.arbitration_id(1, 0x0C) == 0x2C
    assert cansimple.split_arbitration_id(0x6D) == (3, cansimple.CMD_SET_INPUT_VEL)
    assert cansimple.encode_set_input_vel(1.5) == struct.pack("<ff", 1.5, 0.0)
    assert cansimple.encode_set_input_vel(1.5) == bytes.fromhex("0000c03f00000000")
    assert cansimple.encode_set_axis_state(8) == bytes.fromhex("08000000")
    assert cansimple.encode_set_controller_mode(2, 1) == bytes.fromhex("0200000001000000")


def test_decoders_read_heartbeat_and_estimates() -> None:
    heartbeat = cansimple.decode_heartbeat(bytes.fromhex("4000000008000100"))
    assert (heartbeat.axis_error, heartbeat.axis_state) == (0x40, 8)
    estimate = cansimple.decode_encoder_estimates(struct.pack("<ff", -2.25, 0.5))
    assert (estimate.pos_rev, estimate.vel_rev_s) == (-2.25, 0.5)


def test_the_odrive_side_of_the_frames_matches_cansimple() -> None:
    assert (cansimple.CMD_HEARTBEAT, cansimple.CMD_GET_ENCODER_ESTIMATES) == (0x01, 0x09)
    assert cansimple.encode_heartbeat(0x40, 8) == bytes.fromhex("4000000008000100")
    assert cansimple.encode_encoder_estimates(-2.25, 0.5) == struct.pack("<ff", -2.25, 0.5)
    assert cansimple.encode_error(0x800) == bytes.fromhex("0008000000000000")
    assert cansimple.decode_set_input_vel(bytes.fromhex("0000c03f00000000")) == (1.5, 0.0)
    assert cansimple.decode_set_axis_state(bytes.fromhex("08000000")) == 8
    assert cansimple.decode_set_controller_mode(bytes.fromhex("0200000001000000")) == (2, 1)
    with pytest.raises(cansimple.FrameError, match="Set_Input_Vel needs 8 data bytes, got 4"):
        cansimple.decode_set_input_vel(b"\x00" * 4)
    with pytest.raises(cansimple.FrameError, match=r"velocity \(bytes 0-3\) is not finite"):
        cansimple.decode_set_input_vel(struct.pack("<ff", math.nan, 0.0))


def test_bad_frames_are_refused_with_the_reason() -> None:
    with pytest.raises(cansimple.FrameError, match="at least 5 data bytes, got 3"):
        cansimple.decode_heartbeat(b"\x00\x00\x00")
    with pytest.raises(cansimple.FrameError, match="8 data bytes, got 4"):
        cansimple.decode_encoder_estimates(b"\x00" * 4)
    with pytest.raises(cansimple.FrameError, match=r"position \(bytes 0-3\) is not finite"):
        cansimple.decode_encoder_estimates(struct.pack("<ff", math.nan, 0.0))
    with pytest.raises(cansimple.FrameError, match=r"node id must be 0\.\.63, got 64"):
        cansimple.arbitration_id(64, 1)
    with pytest.raises(cansimple.FrameError, match="finite"):
        cansimple.encode_set_input_vel(math.inf)


def test_config_errors_name_the_problem() -> None:
    with pytest.raises(ValueError, match="left_node_id and right_node_id must differ"):
        ODriveCanDriver({"left_node_id": 2, "right_node_id": 2}, max_wheel_speed=1.0)
    interface: Option = ODriveCanDriver.OPTIONS["interface"]
    assert interface.validate("virtual")[1] is None
    _, err = interface.validate("vcan")
    assert err is not None and "unknown python-can interface 'vcan'" in err
    assert "socketcan" in err


# -- control -----------------------------------------------------------------------------------


async def test_open_zeroes_input_then_enters_velocity_closed_loop(
        odrive: Rig, make_driver: Callable[..., ODriveCanDriver]) -> None:
    emulator = odrive.emulator
    # a set-point left over from an earlier run must not move the wheels on arming
    for axis in emulator.axes.values():
        axis.input_vel_rev_s = 3.0
    seen: list[tuple[int, int]] = []
    emulator.frame_hooks.append(lambda node, cmd, data, t: seen.append((node, cmd)))
    driver = make_driver(input_mode="vel_ramp")
    await driver.open()
    for node in (LEFT_NODE, RIGHT_NODE):
        axis = emulator.axes[node]
        assert axis.axis_state == cansimple.AXIS_STATE_CLOSED_LOOP_CONTROL
        assert (axis.control_mode, axis.input_mode) == (2, 2)
        assert axis.input_vel_rev_s == 0.0
        commands = [cmd for n, cmd in seen if n == node]
        assert commands[:4] == [cansimple.CMD_CLEAR_ERRORS, cansimple.CMD_SET_INPUT_VEL,
                                cansimple.CMD_SET_CONTROLLER_MODE, cansimple.CMD_SET_AXIS_STATE]
    assert emulator.wheel_targets() == (0.0, 0.0)
    assert driver.health()["status"] == "ok"


async def test_set_input_vel_is_in_turns_per_second_with_inversion_and_gearing(
        odrive: Rig, make_driver: Callable[..., ODriveCanDriver]) -> None:
    emulator = odrive.emulator
    emulator.gear_ratio = 2.0
    driver = make_driver(gear_ratio=2.0)
    await driver.open()
    await driver.set_wheel_speeds(2 * math.pi, math.pi)
    left, right = emulator.axis("left"), emulator.axis("right")
    await eventually(lambda: left.input_vel_rev_s != 0 and right.input_vel_rev_s != 0,
                     what="Set_Input_Vel on both axes")
    # one wheel turn per second is two motor turns; the mirrored right motor turns backwards
    assert left.input_vel_rev_s == pytest.approx(2.0)
    assert right.input_vel_rev_s == pytest.approx(-1.0)
    assert emulator.wheel_targets() == pytest.approx((2 * math.pi, math.pi))


TWISTS = {
    "forward": (0.4, 0.0),
    "reverse": (-0.3, 0.0),
    "turn_in_place": (0.0, 1.2),
    "arc": (0.25, -0.5),
    "stop": (0.0, 0.0),
}


@pytest.mark.parametrize("name", list(TWISTS))
async def test_wheels_follow_the_commanded_twist(
        name: str, odrive: Rig, make_driver: Callable[..., ODriveCanDriver]) -> None:
    linear, angular = TWISTS[name]
    left = (linear - angular * WHEEL_SEPARATION / 2) / WHEEL_RADIUS
    right = (linear + angular * WHEEL_SEPARATION / 2) / WHEEL_RADIUS
    driver = make_driver()
    await driver.open()
    await driver.set_wheel_speeds(1.0, 1.0)  # so "stop" has something to stop
    await eventually(lambda: close_to(odrive.observed_targets(), (1.0, 1.0), EXACT), "warm-up")
    await driver.set_wheel_speeds(left, right)
    await eventually(lambda: close_to(odrive.observed_targets(), (left, right), EXACT),
                     what=f"wheel targets {left:.3f}, {right:.3f}")
    await eventually(lambda: close_to(odrive.motors.speeds(), (left, right), 1e-3),
                     what="the motors to reach the set-points")


async def test_speeds_beyond_the_limit_are_clamped(
        odrive: Rig, make_driver: Callable[..., ODriveCanDriver]) -> None:
    driver = make_driver()
    await driver.open()
    assert await driver.set_wheel_speeds(100.0, -100.0) == (MAX_WHEEL_SPEED, -MAX_WHEEL_SPEED)
    await eventually(lambda: close_to(odrive.observed_targets(),
                                      (MAX_WHEEL_SPEED, -MAX_WHEEL_SPEED), EXACT))


async def test_close_zeroes_and_idles_both_axes(
        odrive: Rig, make_driver: Callable[..., ODriveCanDriver]) -> None:
    driver = make_driver()
    await driver.open()
    await driver.set_wheel_speeds(5.0, 5.0)
    await eventually(lambda: odrive.observed_targets() == pytest.approx((5.0, 5.0)))
    await driver.close()
    axes = odrive.emulator.axes.values()
    await eventually(lambda: all(a.axis_state == cansimple.AXIS_STATE_IDLE for a in axes),
                     what="IDLE")
    assert all(a.input_vel_rev_s == 0.0 for a in axes)
    assert odrive.observed_targets() == (0.0, 0.0)


async def test_keepalive_feeds_the_odrive_watchdog(
        odrive: Rig, make_driver: Callable[..., ODriveCanDriver]) -> None:
    emulator = odrive.emulator
    emulator.watchdog_timeout_s = 0.5
    fed = make_driver(keepalive_period_s=0.05)
    await fed.open()
    await fed.set_wheel_speeds(2.0, 2.0)
    frames_before = emulator.axis("left").frames[cansimple.CMD_SET_INPUT_VEL]
    await eventually(
        lambda: emulator.axis("left").frames[cansimple.CMD_SET_INPUT_VEL] >= frames_before + 25,
        what="keep-alive frames over more than two watchdog periods")
    assert fed.fault is None
    assert emulator.axis("left").axis_state == cansimple.AXIS_STATE_CLOSED_LOOP_CONTROL
    await fed.close()

    starved = make_driver(keepalive_period_s=0.0)
    await starved.open()
    await starved.set_wheel_speeds(2.0, 2.0)
    reason = await eventually(lambda: starved.fault, what="the watchdog trip to be noticed")
    assert "axis error 0x00000800" in reason
    assert odrive.observed_targets() == (0.0, 0.0)


# -- odometry ----------------------------------------------------------------------------------


def integrate_pose(samples: list[tuple[float, float]]) -> tuple[float, float, float]:
    """Diff-drive dead reckoning over a series of wheel positions (rad)."""
    x = y = theta = 0.0
    for (l0, r0), (l1, r1) in itertools.pairwise(samples):
        d_left, d_right = (l1 - l0) * WHEEL_RADIUS, (r1 - r0) * WHEEL_RADIUS
        distance, turn = (d_left + d_right) / 2, (d_right - d_left) / WHEEL_SEPARATION
        x += distance * math.cos(theta + turn / 2)
        y += distance * math.sin(theta + turn / 2)
        theta += turn
    return x, y, theta


class ScaledClock:
    """Monotonic time running ``scale`` times faster, so the drive takes a fraction of real time."""

    def __init__(self, scale: float) -> None:
        self.scale, self.origin = scale, time.monotonic()

    def __call__(self) -> float:
        return self.origin + (time.monotonic() - self.origin) * self.scale


async def test_odometry_of_1m_straight_and_90_degree_turn_matches_ground_truth(
        tmp_path: Path) -> None:
    motors = MotorPair(clock=ScaledClock(5.0))
    tau = motors.left.time_constant_s  # after a stop command a wheel still turns speed * tau
    with odrive_rig(tmp_path, motors) as odrive:
        driver = ODriveCanDriver(odrive.options, max_wheel_speed=MAX_WHEEL_SPEED)
        await driver.open()
        try:
            start = driver.read_encoders()
            assert start is not None
            measured = [(start.left_rad, start.right_rad)]
            truth = [motors.positions()]

            async def drive(left: float, right: float, done: Callable[[], bool]) -> None:
                await driver.set_wheel_speeds(left, right)
                while not done():
                    await sample()
                await driver.set_wheel_speeds(0.0, 0.0)
                await eventually(lambda: close_to(motors.speeds(), (0.0, 0.0), 1e-6),
                                 what="the wheels to stop")
                # the settled estimate must reach the driver before the last sample
                await eventually(lambda: _reading_matches(driver, motors), what="estimates")
                await sample()

            async def sample() -> None:
                await asyncio.sleep(0.003)
                reading = driver.read_encoders()
                assert reading is not None
                measured.append((reading.left_rad, reading.right_rad))
                truth.append(motors.positions())

            def travelled() -> float:
                return integrate_pose(truth)[0]

            def turned() -> float:
                return integrate_pose(truth)[2]

            coast_m = 10.0 * tau * WHEEL_RADIUS
            await drive(10.0, 10.0, lambda: travelled() + coast_m >= 1.0)
            coast_rad = 2 * 5.0 * tau * WHEEL_RADIUS / WHEEL_SEPARATION
            await drive(-5.0, 5.0, lambda: turned() + coast_rad >= math.radians(90))
        finally:
            await driver.close()

    x, y, theta = integrate_pose(measured)
    x_true, y_true, theta_true = integrate_pose(truth)
    # the scenario ran (a loaded machine samples late and overshoots; odometry must follow)
    assert 0.94 <= x_true <= 1.4
    assert 87.0 <= math.degrees(theta_true) <= 130.0
    assert math.hypot(x - x_true, y - y_true) <= 0.02 * math.hypot(x_true, y_true)
    assert abs(math.degrees(theta - theta_true)) <= 2.0
    left_true, right_true = motors.positions()
    assert measured[-1] == pytest.approx((left_true, right_true), rel=1e-4, abs=1e-4)


def _reading_matches(driver: ODriveCanDriver, motors: MotorPair) -> bool:
    left, right = driver._left, driver._right
    if left.estimate is None or right.estimate is None:
        return False
    positions = (driver._rev_to_rad(left, left.estimate.pos_rev),
                 driver._rev_to_rad(right, right.estimate.pos_rev))
    return close_to(positions, motors.positions(), 1e-4)


# -- faults ------------------------------------------------------------------------------------


async def driving(odrive: Rig, make_driver: Callable[..., ODriveCanDriver],
                  left: float, right: float) -> ODriveCanDriver:
    """A driver opened (short start-up timeout) and driving the emulated wheels."""
    driver = make_driver(startup_timeout_s=0.5)
    await driver.open()
    await drives(odrive, driver, left, right)
    return driver


async def drives(odrive: Rig, driver: ODriveCanDriver, left: float, right: float) -> None:
    await driver.set_wheel_speeds(left, right)
    await eventually(lambda: odrive.observed_targets() == pytest.approx((left, right)))


async def reopens_still_then_drives(odrive: Rig, driver: ODriveCanDriver, speed: float) -> None:
    """After a fault: open() again leaves the wheels still until a fresh command drives them."""
    await driver.open()
    assert odrive.observed_targets() == (0.0, 0.0)
    await drives(odrive, driver, speed, speed)


async def test_heartbeat_loss_faults_zeroes_and_recovers(
        odrive: Rig, make_driver: Callable[..., ODriveCanDriver]) -> None:
    emulator = odrive.emulator
    driver = await driving(odrive, make_driver, 6.0, 6.0)

    emulator.set_heartbeat(False)
    reason = await eventually(lambda: driver.fault, what="the heartbeat loss to be noticed")
    assert f"no heartbeat from ODrive node {LEFT_NODE} (left)" in reason
    assert driver.health()["status"] == "error"
    # the ODrive still listens: the driver zeroed its velocity inputs on noticing
    await eventually(lambda: odrive.observed_targets() == (0.0, 0.0), what="wheels zeroed")
    with pytest.raises(DriverFault, match="no heartbeat from ODrive node"):
        await driver.set_wheel_speeds(3.0, 3.0)
    await driver.set_wheel_speeds(0.0, 0.0)  # zero is always sent
    await driver.close()

    with pytest.raises(DriverFault, match=r"waited 0\.5 s for a heartbeat"):
        await driver.open()
    await driver.close()

    emulator.set_heartbeat(True)
    await reopens_still_then_drives(odrive, driver, 2.0)
    assert driver.fault is None and driver.health()["status"] == "ok"
    reading = driver.read_encoders()
    assert reading is not None
    assert close_to((reading.left_rad, reading.right_rad), odrive.motors.positions(), 0.05)


async def test_axis_error_faults_and_reopen_clears_it_once_the_cause_is_gone(
        odrive: Rig, make_driver: Callable[..., ODriveCanDriver]) -> None:
    emulator = odrive.emulator
    driver = await driving(odrive, make_driver, 4.0, -4.0)

    emulator.inject_axis_error(cansimple.ERROR_MOTOR_FAILED, RIGHT_NODE, persistent=True)
    reason = await eventually(lambda: driver.fault, what="the axis error to be noticed")
    assert reason == (f"ODrive node {RIGHT_NODE} (right) reports axis error 0x00000040 "
                      "in state IDLE")
    await eventually(lambda: odrive.observed_targets() == (0.0, 0.0), what="wheels zeroed")
    await driver.close()

    with pytest.raises(DriverFault, match=r"closed-loop control.*axis error 0x00000040"):
        await driver.open()
    await driver.close()

    emulator.clear_error_condition()
    # open() sends Clear_Errors: the latched error is cleared, then the axis arms again
    await reopens_still_then_drives(odrive, driver, 1.0)
    assert emulator.axis("right").axis_error == 0


async def test_node_off_the_bus_faults_and_reconnects_when_back(
        odrive: Rig, make_driver: Callable[..., ODriveCanDriver]) -> None:
    emulator = odrive.emulator
    driver = make_driver(startup_timeout_s=0.5)
    await driver.open()
    await driver.set_wheel_speeds(3.0, 3.0)
    emulator.set_online(False, LEFT_NODE)
    reason = await eventually(lambda: driver.fault)
    assert "no heartbeat" in reason or "no encoder estimates" in reason
    await eventually(lambda: emulator.axis("right").input_vel_rev_s == 0.0,
                     what="the reachable axis to be zeroed")
    await driver.close()
    emulator.set_online(True, LEFT_NODE)
    await driver.open()
    assert odrive.observed_targets() == (0.0, 0.0)


async def test_a_vanished_can_interface_faults_and_reopens(
        odrive: Rig, make_driver: Callable[..., ODriveCanDriver]) -> None:
    driver = make_driver()
    await driver.open()
    assert driver._bus is not None
    driver._bus.shutdown()  # what a CAN adapter unplugged under the driver looks like
    reason = await eventually(lambda: driver.fault, what="the receive failure to be noticed")
    assert reason.startswith("CAN receive on virtual channel"), reason
    with pytest.raises(DriverFault):
        await driver.set_wheel_speeds(1.0, 1.0)
    assert not await driver.try_zero()
    await driver.close()
    await driver.open()
    await driver.set_wheel_speeds(1.0, 1.0)
    await eventually(lambda: odrive.observed_targets() == pytest.approx((1.0, 1.0)))


async def test_garbled_frames_are_counted_not_trusted(
        odrive: Rig, make_driver: Callable[..., ODriveCanDriver]) -> None:
    driver = make_driver()
    await driver.open()
    with can.Bus(interface="virtual", channel=odrive.emulator.channel) as bus:
        bus.send(can.Message(arbitration_id=cansimple.arbitration_id(LEFT_NODE, 0x09),
                             data=struct.pack("<ff", math.nan, 0.0), is_extended_id=False))
        bus.send(can.Message(arbitration_id=cansimple.arbitration_id(RIGHT_NODE, 0x01),
                             data=b"\x01", is_extended_id=False))
        await eventually(lambda: driver.bad_frames == 2, what="two bad frames")
    assert "not finite" in driver.health()["last_bad_frame"] or "5 data bytes" in \
        driver.health()["last_bad_frame"]
    reading = driver.read_encoders()
    assert reading is not None and math.isfinite(reading.left_rad)
    assert driver.fault is None


async def test_open_without_an_odrive_names_the_missing_nodes(tmp_path: Path) -> None:
    driver = ODriveCanDriver({"interface": "virtual", "channel": f"empty-{uuid.uuid4().hex}",
                              "startup_timeout_s": 0.3}, max_wheel_speed=1.0)
    with pytest.raises(DriverFault, match=r"ODrive node 0 \(left\): no heartbeat"):
        await driver.open()
    await driver.close()


async def test_open_on_a_missing_can_device_is_a_driver_fault() -> None:
    driver = ODriveCanDriver({"interface": "socketcan", "channel": "arbiterd-none0"},
                             max_wheel_speed=1.0)
    with pytest.raises(DriverFault, match="open failed"):
        await driver.open()


# -- safe-stop ---------------------------------------------------------------------------------


async def test_safe_stop_idles_axes_left_running_by_a_dead_daemon(
        odrive: Rig, make_driver: Callable[..., ODriveCanDriver]) -> None:
    abandoned = make_driver(keepalive_period_s=0.0)
    await abandoned.open()
    await abandoned.set_wheel_speeds(5.0, 5.0)
    await eventually(lambda: odrive.observed_targets() == pytest.approx((5.0, 5.0)))

    await make_driver().safe_stop()
    assert odrive.observed_targets() == (0.0, 0.0)
    assert all(a.axis_state == cansimple.AXIS_STATE_IDLE for a in odrive.emulator.axes.values())


async def test_safe_stop_without_an_answer_says_so() -> None:
    driver = ODriveCanDriver({"interface": "virtual", "channel": f"empty-{uuid.uuid4().hex}"},
                             max_wheel_speed=1.0)
    with pytest.raises(DriverFault, match="no IDLE heartbeat came back from ODrive node 0"):
        await driver.safe_stop()


# -- across processes: the standalone emulator on udp_multicast ---------------------------------


def _free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("", 0))
        port: int = sock.getsockname()[1]
        return port


@pytest.fixture
def emulator_process() -> Iterator[tuple[subprocess.Popen[str], int]]:
    port = _free_udp_port()
    try:
        probe = can.Bus(interface="udp_multicast", channel=MULTICAST_GROUP, port=port)
    except (can.CanError, OSError, ImportError) as exc:
        pytest.skip(f"python-can udp_multicast unusable here: {exc}")
    probe.shutdown()
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.odrive_emulator", "--interface", "udp_multicast",
         "--channel", MULTICAST_GROUP, "--port", str(port), "--left-node", "5",
         "--right-node", "6"], cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
        text=True)
    assert proc.stdout is not None
    assert "ODrive emulator on interface udp_multicast" in proc.stdout.readline()
    assert "multicast_port" in proc.stdout.readline()
    yield proc, port
    proc.terminate()
    assert proc.wait(10) == 0


async def test_standalone_emulator_in_another_process_over_udp_multicast(
        emulator_process: tuple[subprocess.Popen[str], int]) -> None:
    proc, port = emulator_process
    assert proc.stdin is not None and proc.stdout is not None
    driver = ODriveCanDriver({"interface": "udp_multicast", "channel": MULTICAST_GROUP,
                              "multicast_port": port, "left_node_id": 5, "right_node_id": 6},
                             max_wheel_speed=MAX_WHEEL_SPEED)
    await driver.open()
    try:
        await driver.set_wheel_speeds(2 * math.pi, 2 * math.pi)

        def command(line: str) -> str:
            proc.stdin.write(line + "\n")  # type: ignore[union-attr]
            proc.stdin.flush()  # type: ignore[union-attr]
            return proc.stdout.readline()  # type: ignore[union-attr]

        async def status_shows(*parts: str) -> str:
            """The emulator's status once it shows ``parts`` (the frames cross processes over
            UDP: the command may still be on its way when the status is asked)."""
            latest = ""

            async def shown() -> bool:
                nonlocal latest
                latest = await asyncio.to_thread(command, "status")
                return all(part in latest for part in parts)

            deadline = time.monotonic() + 10.0
            while not await shown():
                assert time.monotonic() < deadline, f"status never showed {parts}: {latest}"
            return latest

        await status_shows("node 5 state 8", "vel 1.000", "vel -1.000")
        assert (await asyncio.to_thread(command, "heartbeat off")).startswith("ok")
        reason = await eventually(lambda: driver.fault, what="heartbeat loss across processes")
        assert "no heartbeat from ODrive node 5" in reason
        await driver.close()
        assert (await asyncio.to_thread(command, "heartbeat on")).startswith("ok")
        await driver.open()
        assert driver.fault is None
        await status_shows("vel 0.000")
    finally:
        await driver.close()


def test_bench_measures_every_command_reaching_the_emulated_odrive() -> None:
    from daemon.bench.driver_odrive import run

    results = {r.name: r for r in run(quick=True)}
    sent = results["odrive_can virtual command->sent p99"]
    reached = results["odrive_can virtual command->ODrive p50"]
    assert sent.suite == "drivers" and sent.unit == "ms"
    assert math.isfinite(sent.value) and sent.value > 0
    assert "(300 matched)" in reached.note


# -- end to end: the real daemon as a subprocess, the ODrive emulated in this process --------


def test_daemon_survives_odrive_heartbeat_loss(tmp_path: Path) -> None:
    from tests.support.daemon_subprocess import DaemonSubprocess

    port = _free_udp_port()
    try:
        emulator = ODriveEmulator("udp_multicast", MULTICAST_GROUP, node_ids=(7, 8),
                                  bus_kwargs={"port": port}).start()
    except (can.CanError, OSError, ImportError) as exc:
        pytest.skip(f"python-can udp_multicast unusable here: {exc}")
    config = f"""
[driver]
type = "odrive_can"
[driver.odrive_can]
interface = "udp_multicast"
channel = "{MULTICAST_GROUP}"
multicast_port = {port}
left_node_id = 7
right_node_id = 8
[control]
reconnect_min_s = 0.2
reconnect_max_s = 0.5
"""
    drive = {"linear": {"x": 0.2}}  # 4 rad/s on both 0.05 m wheels
    try:
        with DaemonSubprocess(tmp_path, config, use_mock_log=False) as daemon:
            wait_for(lambda: daemon.get("/api/health")[0] == 200, "a healthy daemon", within_s=10)

            def driving() -> bool:
                assert daemon.post("/api/cmd_vel", drive)[0] == 200
                return close_to(emulator.wheel_targets(), (4.0, 4.0), 0.05)

            wait_for(driving, "the emulated wheels to turn at 4 rad/s", within_s=5)

            emulator.set_heartbeat(False)
            status, health = wait_for(lambda: _health_if(daemon, 503), "health error", within_s=5)
            assert health["status"] == "error"
            assert "no heartbeat from ODrive node 7" in json.dumps(health)
            wait_for(lambda: emulator.wheel_targets() == (0.0, 0.0), "wheels zeroed", within_s=2)
            status, body = daemon.post("/api/cmd_vel", drive)
            assert status == 409 and "fault" in body["error"]

            emulator.set_heartbeat(True)
            wait_for(lambda: _health_if(daemon, 200), "recovery after the heartbeat returns",
                     within_s=10)
            left = emulator.axis("left")
            frames = left.frames[cansimple.CMD_SET_INPUT_VEL]
            assert left.axis_state == cansimple.AXIS_STATE_CLOSED_LOOP_CONTROL
            wait_for(lambda: left.frames[cansimple.CMD_SET_INPUT_VEL] >= frames + 5,
                     "keep-alive frames after the reconnect", within_s=5)
            assert emulator.wheel_targets() == (0.0, 0.0)  # still until a fresh command
            wait_for(driving, "motion after a fresh command", within_s=5)

            assert daemon.proc is not None and daemon.proc.poll() is None
            assert daemon.stop() == 0
        axes = emulator.axes.values()
        wait_for(lambda: all(a.axis_state == cansimple.AXIS_STATE_IDLE for a in axes),
                 "both axes IDLE after the daemon's shutdown", within_s=2)
    finally:
        emulator.stop()


def _health_if(daemon: Any, wanted: int) -> tuple[int, Any] | None:
    status, body = daemon.get("/api/health")
    return (status, body) if status == wanted else None


def test_arbiterd_safe_stop_idles_a_running_odrive(tmp_path: Path) -> None:
    port = _free_udp_port()
    try:
        emulator = ODriveEmulator("udp_multicast", MULTICAST_GROUP, node_ids=(9, 10),
                                  bus_kwargs={"port": port}).start()
    except (can.CanError, OSError, ImportError) as exc:
        pytest.skip(f"python-can udp_multicast unusable here: {exc}")
    try:
        emulator.set_running(1.0)  # as a crashed daemon would leave it: armed and turning
        assert emulator.wheel_targets() != (0.0, 0.0)
        config = tmp_path / "arbiterd.toml"
        config.write_text(f'[driver]\ntype = "odrive_can"\n[driver.odrive_can]\n'
                          f'interface = "udp_multicast"\nchannel = "{MULTICAST_GROUP}"\n'
                          f"multicast_port = {port}\nleft_node_id = 9\nright_node_id = 10\n")
        done = subprocess.run([sys.executable, "-m", "daemon.cli", "safe-stop", "--config",
                               str(config)], cwd=REPO, capture_output=True, text=True,
                              timeout=30)
        assert done.returncode == 0, done.stderr
        assert "motors zeroed through the odrive_can driver" in done.stdout
        assert emulator.wheel_targets() == (0.0, 0.0)
        assert all(a.axis_state == cansimple.AXIS_STATE_IDLE for a in emulator.axes.values())
    finally:
        emulator.stop()
