# Safety that survives a stalled event loop: every driver's emergency path, the supervisor thread
# in the control loop, and a 3 s injected stall against `arbiterd run` seen from the devices.
from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from daemon.cli import _toml_value
from daemon.commands import Twist
from daemon.components.control.supervisor import StallSupervisor
from drivers import DRIVERS, create_driver, driver_class
from drivers.mock import MockDriver
from sim.motor_model import MotorPair, WheelMotor
from sim.wiring import EMULATORS
from tests.support.compare import close_to
from tests.support.daemon_subprocess import DaemonSubprocess, StartDaemonSubprocess
from tests.support.in_process_daemon import in_process_daemon
from tests.support.rigs import FULL_DUTY_SPEED, Rig, wired_rig
from tests.support.wait import eventually, wait_for

pytestmark = pytest.mark.timeout(90)

MAX_WHEEL_SPEED = 10.0
STALL_STOP_S = 0.2
#: thread scheduling and one request's way into the daemon, on a loaded CI machine
SLACK_S = 0.2
STILL = (0.0, 0.0)

Record = list[tuple[float, tuple[float, float]]]

#: drivers that re-send a held speed on their own: a counter that shows the keep-alive had its
#: chance, and by how much it must grow (serial: 'e' polls at 50 Hz, the keep-alive checks
#: after each, 0.5 s hold; odrive_can: two Set_Input_Vel frames every 0.1 s)
KEEPALIVES: dict[str, tuple[Callable[[Any], int], int]] = {
    "serial": (lambda driver: driver.polls, 40),
    "odrive_can": (lambda driver: driver.frames_tx, 12),
}


def still(targets: tuple[float, float]) -> bool:
    return close_to(targets, STILL, 1e-9)


# -- the driver's emergency path, per registered driver ----------------------------------------


def test_every_registered_driver_implements_the_emergency_path() -> None:
    missing = [name for name in DRIVERS if driver_class(name).__abstractmethods__]
    assert missing == []


async def test_emergency_stop_reaches_the_device_while_the_loop_is_blocked(rig: Rig) -> None:
    driver = rig.make_driver(MAX_WHEEL_SPEED)
    assert driver.emergency_stop() is False  # not open yet: nothing to stop
    await driver.open()
    try:
        await driver.set_wheel_speeds(4.0, 4.0)
        await eventually(lambda: min(map(abs, rig.observed_targets())) > 1.0,
                         "the device to turn both wheels")
        loop_ran = threading.Event()
        asyncio.get_running_loop().call_soon(loop_ran.set)
        answer: list[bool] = []
        stopper = threading.Thread(target=lambda: answer.append(driver.emergency_stop()))
        stopper.start()
        # wait_for sleeps in this thread: the event loop is blocked until the device is still
        wait_for(lambda: still(rig.observed_targets()), "the device to see zero")
        assert not loop_ran.is_set(), "the event loop ran during the emergency stop"
        stopper.join()
        assert answer == [True]
        health = driver.health()
        assert (health["emergency_stops"], health["emergency_failures"]) == (1, 0)

        # the loop runs again: no keep-alive brings the old speed back ...
        if rig.driver_name in KEEPALIVES:
            counter, grow = KEEPALIVES[rig.driver_name]
            start = counter(driver)
            await eventually(lambda: counter(driver) >= start + grow,
                             "the driver's keep-alive to have its chance")
        assert still(rig.observed_targets()), "the driver re-sent an older speed"
        # ... and the driver took no harm: it drives on request
        await driver.set_wheel_speeds(3.0, 3.0)
        await eventually(lambda: min(map(abs, rig.observed_targets())) > 1.0,
                         "the device to turn again")
        assert driver.fault is None, driver.fault
    finally:
        await driver.close()
    assert driver.emergency_stop() is False  # closed: a no-op
    assert driver.health()["emergency_stops"] == 1


async def test_emergency_stop_against_a_hung_pigpiod_gives_up_and_says_so(tmp_path: Path) -> None:
    with wired_rig("pigpio", tmp_path, timeout=0.2, watch_interval=0.0) as rig:
        driver = create_driver("pigpio", rig.options, max_wheel_speed=MAX_WHEEL_SPEED)
        await driver.open()
        try:
            await driver.set_wheel_speeds(4.0, 4.0)
            rig.emulator.unresponsive = True
            answer: list[bool] = []
            stopper = threading.Thread(target=lambda: answer.append(driver.emergency_stop()))
            stopper.start()
            stopper.join(timeout=10.0)
            assert not stopper.is_alive(), "emergency_stop() did not return"
            assert answer == [False]
            health = driver.health()
            assert (health["emergency_stops"], health["emergency_failures"]) == (1, 1)
            assert "Timeout" in health["last_emergency_error"]
        finally:
            rig.emulator.unresponsive = False
            await driver.close()


class ExplodingDriver(MockDriver):
    def _emergency_zero(self) -> bool:
        raise OSError("bus on fire")


async def test_emergency_stop_never_raises_and_counts_failures() -> None:
    driver = ExplodingDriver({}, max_wheel_speed=MAX_WHEEL_SPEED)
    await driver.open()
    await driver.set_wheel_speeds(1.0, 1.0)
    assert driver.emergency_stop() is False
    health = driver.health()
    assert (health["emergency_stops"], health["emergency_failures"]) == (1, 1)
    assert health["last_emergency_error"] == "OSError: bus on fire"
    assert health["last_command_rad_s"] == [1.0, 1.0]  # nothing claims the wheels stopped
    await driver.close()


# -- the supervisor in the control loop (in-process robot, mock driver) ------------------------


class CountingSupervisor(StallSupervisor):
    """Counts the thread's checks of the tick."""

    checks = 0

    def check(self) -> float:
        self.checks += 1
        return super().check()


async def test_at_rest_the_supervisor_sleeps_and_a_turning_wheel_wakes_it() -> None:
    """While the wheels were last told zero there is nothing to stop: the thread does not
    check the tick at all. A write that turns a wheel wakes it, and a stall then stops them."""
    driver = MockDriver({}, max_wheel_speed=MAX_WHEEL_SPEED)
    await driver.open()
    supervisor = CountingSupervisor(driver, STALL_STOP_S / 4)
    supervisor.start()
    try:
        for _ in range(8):  # two stall periods of a beating loop at rest, then none at all
            supervisor.beat()
            await asyncio.sleep(STALL_STOP_S / 16)
        await asyncio.sleep(STALL_STOP_S)  # a stall at rest: nothing to stop
        assert (supervisor.checks, supervisor.stall_stops) == (0, 0)

        supervisor.beat()
        await driver.set_wheel_speeds(2.0, 2.0)
        supervisor.turning()  # then no more beats: the loop stalls with the wheels turning
        wait_for(lambda: driver.commands[-1][1:] == STILL, "the supervisor to zero the wheels")
        assert supervisor.checks >= 1 and supervisor.stall_stops == 1
        wait_for(lambda: supervisor._watched is False, "the supervisor to sleep again")
    finally:
        supervisor.stop()
        await driver.close()




async def test_a_blocked_event_loop_cannot_keep_the_robot_driving(tmp_path: Path) -> None:
    # a deadman far longer than the stall: only the supervisor can stop the wheels in time,
    # and the command is still "live" when the loop comes back
    extra = f"[control]\ncmd_vel_timeout = 10.0\nstall_stop_s = {STALL_STOP_S}\n"
    async with in_process_daemon(tmp_path, extra) as robot:
        control, driver = robot.control, robot.driver
        stops_before = control.supervisor.stall_stops  # a loaded machine may stall at start
        emergencies_before = driver.emergency_stops
        applied = await control.submit("teleop", Twist(0.3, 0.0), t_recv=time.monotonic())
        assert applied.accepted and robot.moving()
        blocked_at = time.monotonic()
        wait_for(lambda: not robot.moving(), "the supervisor to zero the wheels")  # loop blocked
        zeroed = driver.commands[-1]
        assert zeroed.t_mono - blocked_at <= STALL_STOP_S + SLACK_S
        assert control.supervisor.stall_stops == stops_before + 1  # one stall, one stop
        assert driver.emergency_stops == emergencies_before + 1

        ticks: list[float] = []
        control.on_tick.add(lambda now, on_time: ticks.append(now))
        await eventually(lambda: len(ticks) >= 25, "the control tick to run again")
        assert all(still((c.left_rad_s, c.right_rad_s)) for c in driver.commands
                   if c.t_mono >= zeroed.t_mono), "the wheels moved after the stall stop"
        health = control.health()
        assert health["status"] == "ok" and health["stalled"] is False
        assert health["stall_stops"] == stops_before + 1
        assert health["last_stall_ms"] >= STALL_STOP_S * 1e3
        assert health["longest_stall_ms"] >= health["last_stall_ms"]

        applied = await control.submit("teleop", Twist(0.3, 0.0), t_recv=time.monotonic())
        assert applied.accepted
        await eventually(robot.moving, "a fresh command to move the robot again")


async def test_without_a_supervisor_a_blocked_loop_keeps_driving(tmp_path: Path,
                                                                 caplog: Any) -> None:
    extra = "[control]\ncmd_vel_timeout = 10.0\nstall_stop_s = 0\n"
    async with in_process_daemon(tmp_path, extra) as robot:
        assert "the stall supervisor is DISABLED" in caplog.text
        await robot.control.submit("teleop", Twist(0.3, 0.0), t_recv=time.monotonic())
        time.sleep(STALL_STOP_S * 3)  # noqa: ASYNC251 - the blocked loop is the point
        assert robot.moving()
        assert robot.driver.emergency_stops == 0


# -- must show: a 3 s injected stall against `arbiterd run`, seen from the devices -------------


class RecordingMotors(MotorPair):
    """The emulated motors, remembering every set-point the emulator gave them and when."""

    def __init__(self, counts_per_rev: int, max_speed_rad_s: float = 40.0) -> None:
        super().__init__(WheelMotor(max_speed_rad_s=max_speed_rad_s,
                                    counts_per_rev=counts_per_rev),
                         WheelMotor(max_speed_rad_s=max_speed_rad_s,
                                    counts_per_rev=counts_per_rev))
        self.record: Record = []

    def set_targets(self, left_rad_s: float, right_rad_s: float) -> None:
        super().set_targets(left_rad_s, right_rad_s)
        self.record.append((time.monotonic(), self.targets()))

    def set_duties(self, left: float, right: float) -> None:
        super().set_duties(left, right)
        self.record.append((time.monotonic(), self.targets()))


def driver_toml(driver: str, options: dict[str, Any]) -> str:
    section = "".join(f"{key} = {_toml_value(value)}\n" for key, value in options.items())
    return (f'[driver]\ntype = "{driver}"\n[driver.{driver}]\n{section}'
            f"[control]\nallow_fault_injection = true\ncmd_vel_timeout = 10.0\n"
            f"stall_stop_s = {STALL_STOP_S}\n")


def stall_while_driving(daemon: DaemonSubprocess, record: Callable[[], Record],
                        seconds: float = 3.0) -> tuple[float, float]:
    """Drive, stall the event loop for ``seconds``, check what the device saw, drive again;
    returns when the stall was asked for and when the device was told zero."""
    assert daemon.post("/api/cmd_vel", {"linear": {"x": 0.3}})[0] == 200
    wait_for(lambda: record() and min(record()[-1][1]) > 0.5, "the device to drive")
    asked = time.monotonic()
    status, body = daemon.post("/api/debug/stall", {"seconds": seconds}, timeout=seconds + 10)
    ended = time.monotonic()
    assert status == 200, body
    zero_at = next((t for t, targets in record() if t >= asked and still(targets)), None)
    assert zero_at is not None, "the device was never told to stop"
    assert zero_at < ended - 1.0, "the wheels were zeroed only when the stall ended"
    assert zero_at - asked <= STALL_STOP_S + SLACK_S

    ticks = daemon.get("/api/latency")[1]["tick"]["count"]
    wait_for(lambda: daemon.get("/api/latency")[1]["tick"]["count"] >= ticks + 25,
             "half a second of control ticks after the stall")
    moved = [(t, targets) for t, targets in record() if t > zero_at and not still(targets)]
    assert moved == [], "the wheels moved after the stall without a fresh command"
    control = daemon.get("/api/health")[1]["components"]["control"]
    assert control["stall_stops"] == 1 and control["stalled"] is False
    assert control["longest_stall_ms"] >= seconds * 1e3 * 0.9
    assert control["driver"]["emergency_stops"] == 1
    assert control["driver"]["emergency_failures"] == 0
    assert "control tick stalled" in daemon.log()

    fresh = time.monotonic()
    status, body = daemon.post("/api/cmd_vel", {"linear": {"x": 0.3}})
    assert status == 200, (body, daemon.get("/api/health")[1]["components"]["control"])
    wait_for(lambda: any(t > fresh and min(v) > 0.5 for t, v in record()),
             "a fresh command to drive again")
    return asked, zero_at


def test_injected_stall_serial_board_sees_m_0_0(
        tmp_path: Path, daemon_subprocess: StartDaemonSubprocess) -> None:
    motors = RecordingMotors(EMULATORS["serial"].counts_per_rev)
    with wired_rig("serial", tmp_path, motors) as rig:
        board = rig.emulator
        board.firmware.auto_stop_s = 30.0
        daemon = daemon_subprocess(driver_toml("serial", rig.options), use_mock_log=False)
        asked, zero_at = stall_while_driving(daemon, lambda: list(motors.record))
        lines = [c for c in board.firmware.history if asked <= c.t_mono <= zero_at
                 and c.text[:1] in "mo"]
        assert lines and lines[-1].text == "m 0 0", lines[-3:]
        print(f"serial: 'm 0 0' reached the board {(zero_at - asked) * 1e3:.0f} ms after the "
              "stall request")


def test_injected_stall_pigpiod_sees_duty_zero(
        tmp_path: Path, daemon_subprocess: StartDaemonSubprocess) -> None:
    motors = RecordingMotors(EMULATORS["pigpio"].counts_per_rev, FULL_DUTY_SPEED)
    with wired_rig("pigpio", tmp_path, motors, watch_interval=0.25) as rig:
        daemon = daemon_subprocess(driver_toml("pigpio", rig.options), use_mock_log=False)
        asked, zero_at = stall_while_driving(daemon, lambda: list(motors.record))
        print(f"pigpio: duty 0 reached pigpiod {(zero_at - asked) * 1e3:.0f} ms after the "
              "stall request")


def test_injected_stall_mock_wheel_log_shows_zero(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    daemon = daemon_subprocess("[control]\nallow_fault_injection = true\ncmd_vel_timeout = 10.0\n"
                            f"stall_stop_s = {STALL_STOP_S}\n")

    def record() -> Record:
        return [(t, (left, right)) for t, left, right in daemon.wheels()]

    asked, zero_at = stall_while_driving(daemon, record)
    print(f"mock: zero in the wheel log {(zero_at - asked) * 1e3:.0f} ms after the stall "
          "request")
