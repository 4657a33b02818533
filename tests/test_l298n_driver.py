# The l298n driver through gpiozero: MockFactory pins and PiGPIOFactory on the pigpiod emulator.
from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from drivers.base import DriverFault
from drivers.l298n import L298NDriver, mock_pin_factory
from tests.support.compare import close_to
from tests.support.rigs import RIGS, Rig, restart_pigpiod_and_reopen
from tests.support.wait import eventually

pytestmark = pytest.mark.timeout(60)

MAX_WHEEL_SPEED = 15.0
TOLERANCE = 0.02
#: the l298n driver on gpiozero's mock pins, and through PiGPIOFactory on the emulated pigpiod
mock_rig, pigpio_rig = RIGS["l298n"], RIGS["l298n@pigpio"]


async def opened(the_rig: Rig, **overrides: Any) -> L298NDriver:
    driver = L298NDriver(the_rig.options | overrides, max_wheel_speed=MAX_WHEEL_SPEED)
    await driver.open()
    return driver


@pytest.fixture(params=["l298n", "l298n@pigpio"], ids=["mock-pins", "pigpio-factory"])
def any_rig(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Rig]:
    with RIGS[request.param](tmp_path) as the_rig:
        yield the_rig


async def test_forward_reverse_turn_stop_reach_the_bridges(any_rig: Rig) -> None:
    driver = await opened(any_rig)
    try:
        for left, right in [(6.0, 6.0), (-4.0, -4.0), (-3.0, 3.0), (0.0, 0.0)]:
            await driver.set_wheel_speeds(left, right)
            assert close_to(any_rig.observed_targets(), (left, right), TOLERANCE)
        await driver.set_wheel_speeds(7.0, 7.0)
    finally:
        await driver.close()
    assert any_rig.observed_targets() == (0.0, 0.0)  # close() stopped the wheels


async def test_encoders_follow_the_wheels(any_rig: Rig) -> None:
    driver = await opened(any_rig)
    try:
        await driver.set_wheel_speeds(8.0, -8.0)
        await eventually(lambda: any_rig.motors.positions()[0] > 4.0, "the wheels to turn")
        await driver.stop()
        await eventually(lambda: all(abs(v) < 1e-3 for v in any_rig.motors.speeds()),
                         "the wheels to stop")
        step = 2 * math.pi / any_rig.options["encoder_counts_per_rev"]

        async def agrees() -> bool:
            reading = driver.read_encoders()
            assert reading is not None
            truth = any_rig.motors.positions()
            return abs(reading.left_rad - truth[0]) <= step and \
                abs(reading.right_rad - truth[1]) <= step

        await eventually(agrees, "the encoders to catch up with the wheels")
    finally:
        await driver.close()


async def test_mock_pins_carry_pwm_frequency_enable_and_duty(tmp_path: Path) -> None:
    with mock_rig(tmp_path, left_enable=25, right_enable=26, min_duty=0.2, deadband=0.5,
                        pwm_frequency=1000) as the_rig:
        driver = await opened(the_rig)
        factory = mock_pin_factory()
        try:
            await driver.set_wheel_speeds(10.0, -0.3)  # right: inside the deadband
            pins = {g: factory.pin(g) for g in (17, 18, 22, 23, 25, 26)}
            assert pins[17].state == pytest.approx(0.2 + 0.8 * 0.5)
            assert (pins[18].state, pins[22].state, pins[23].state) == (0, 0, 0)
            assert pins[17].frequency == 1000 and pins[23].frequency == 1000
            assert pins[25].state and pins[26].state  # enables held high
            await driver.set_wheel_speeds(-10.0, 0.0)
            assert (pins[17].state, pins[18].state) == (0, pytest.approx(0.6))
        finally:
            await driver.close()


async def test_per_side_inversion_matches_a_mirrored_motor(tmp_path: Path) -> None:
    with mock_rig(tmp_path, right_motor_inverted=True) as the_rig:  # a mirrored right motor
        driver = await opened(the_rig)
        try:
            await driver.set_wheel_speeds(5.0, 5.0)
            assert close_to(the_rig.observed_targets(), (5.0, 5.0), TOLERANCE)
        finally:
            await driver.close()


def test_a_pin_used_twice_is_refused_naming_both_keys() -> None:
    with pytest.raises(ValueError, match="right_forward = 17 is already used by left_forward"):
        L298NDriver({"right_forward": 17}, max_wheel_speed=10.0)


@pytest.mark.parametrize("factory", ["lgpio", "rpigpio"])
async def test_a_pin_factory_this_machine_lacks_is_a_fault(
        factory: str, tmp_path: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("LG_WD", str(tmp_path))
    driver = L298NDriver({"pin_factory": factory}, max_wheel_speed=10.0)
    with pytest.raises(DriverFault, match=f"pin_factory = '{factory}' unavailable"):
        await driver.open()


async def test_pigpiod_unreachable_is_a_fault(tmp_path: Path) -> None:
    with pigpio_rig(tmp_path) as the_rig:
        the_rig.emulator.stop()
        driver = L298NDriver(the_rig.options, max_wheel_speed=MAX_WHEEL_SPEED)
        with pytest.raises(DriverFault, match=r"pigpiod unreachable at 127\.0\.0\.1"):
            await driver.open()


async def test_pigpiod_stops_and_restarts_under_pigpio_factory(tmp_path: Path) -> None:
    with pigpio_rig(tmp_path) as the_rig:
        emulator = the_rig.emulator
        driver = await opened(the_rig)
        try:
            await driver.set_wheel_speeds(8.0, 8.0)
            await eventually(lambda: the_rig.motors.positions()[0] > 2.0, "the wheels to turn")
            emulator.stop()
            await eventually(lambda: driver.fault is not None, "the keep-alive to notice")
            assert "pigpiod at 127.0.0.1" in (driver.fault or "")
            assert driver.health()["status"] == "error"
            assert the_rig.observed_targets() == (0.0, 0.0)
            before = driver.read_encoders()
            await driver.close()
            await restart_pigpiod_and_reopen(the_rig, driver)
            after = driver.read_encoders()
            assert before is not None and after is not None
            assert (after.left_rad, after.right_rad) == (before.left_rad, before.right_rad)
            await driver.set_wheel_speeds(5.0, 5.0)
            assert close_to(the_rig.observed_targets(), (5.0, 5.0), TOLERANCE)
        finally:
            await driver.close()


async def test_safe_stop_zeroes_pins_a_dead_process_left_driving(tmp_path: Path) -> None:
    with mock_rig(tmp_path) as the_rig:
        factory = mock_pin_factory()
        for gpio in (17, 22):  # forward PWM on both sides, as a crashed daemon left them
            pin = factory.pin(gpio)
            pin.function, pin.frequency, pin.state = "output", 500, 0.6
        assert close_to(the_rig.observed_targets(), (12.0, 12.0), TOLERANCE)
        await L298NDriver(the_rig.options, max_wheel_speed=MAX_WHEEL_SPEED).safe_stop()
        assert the_rig.observed_targets() == (0.0, 0.0)
