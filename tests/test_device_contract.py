# One contract over every registered device (hardware beyond the wheel pair), against its emulator.
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from drivers.device_registry import DEVICES
from drivers.devices import Actuator, DeviceError, create_device, device_class
from sim.wiring import DEVICE_EMULATORS

REPO = Path(__file__).resolve().parent.parent


#: devices with no byte-level emulator: their drivers run against stand-ins of their libraries
#: (picamera2, linuxpy) in tests/components/camera, and the simulator has a camera of its own
LIBRARY_TESTED = frozenset({"picamera2_camera", "v4l2_camera"})


def test_every_registered_device_has_an_emulator_and_docs() -> None:
    assert set(DEVICE_EMULATORS) == set(DEVICES) - LIBRARY_TESTED
    guide = (REPO / "docs" / "adding-a-component.md").read_text()
    for name in DEVICES:
        assert f"`{name}`" in guide, f"docs/adding-a-component.md names the device {name}"


def test_an_unknown_device_names_the_valid_ones() -> None:
    with pytest.raises(DeviceError, match=r"valid devices: .*pigpio_servo"):
        device_class("servo9000")


@pytest.mark.parametrize("name", sorted(set(DEVICES) - LIBRARY_TESTED))
async def test_device_contract(name: str, tmp_path: Path) -> None:
    """Open against the emulator, write, refuse bad targets, report health, close twice."""
    cls = device_class(name)
    section = f"test.{name}"
    emulated = DEVICE_EMULATORS[name](tmp_path, {})
    try:
        device = create_device(name, emulated.options, section=section)
        assert device.health()["status"] == "error"  # not open yet
        await device.open()
        assert device.health()["status"] == "ok"
        if issubclass(cls, Actuator):
            assert isinstance(device, Actuator)
            await _actuator_contract(device, section)
        await device.close()
        await device.close()
        assert not device.is_open
    finally:
        emulated.stop()


async def _actuator_contract(device: Actuator, section: str) -> None:
    joint = device.joints()[0]
    assert await device.write({joint.name: joint.upper + 10.0}) == {joint.name: joint.upper}
    assert device.targets[joint.name] == joint.upper
    with pytest.raises(DeviceError, match=rf"\[{section}\] unknown joint 'nope'; joints:"):
        await device.write({"nope": 0.0})
    with pytest.raises(DeviceError, match="expected a finite number"):
        await device.write({joint.name: math.nan})
    assert device.targets[joint.name] == joint.upper  # nothing changed by the refusals
    await device.relax()


def _servo_options(emulated: Any, **extra: Any) -> dict[str, Any]:
    return {**emulated.options, "joints": ["shoulder", "elbow"], "pins": [12, 13],
            "lower": [-1.5708, 0.0], "upper": [1.5708, 0.035], **extra}


async def test_servo_pulses_on_the_emulated_pins(tmp_path: Path) -> None:
    emulated = DEVICE_EMULATORS["pigpio_servo"](tmp_path, {})
    try:
        device = create_device("pigpio_servo", _servo_options(emulated), section="arm")
        await device.open()
        assert isinstance(device, Actuator)
        await device.write({"shoulder": 0.0, "elbow": 0.035})
        pins = emulated.emulator.bank.pins
        assert (pins[12].servo_us, pins[13].servo_us) == (1500, 2500)
        await device.write({"shoulder": -1.5708})
        assert pins[12].servo_us == 500
        await device.relax()
        assert (pins[12].servo_us, pins[13].servo_us) == (0, 0)
        await device.close()
    finally:
        emulated.stop()


@pytest.mark.parametrize(("extra", "problem"), [
    ({"pins": [12]}, r"\[arm\] joints, pins, lower and upper need one entry per joint"),
    ({"pins": [12, 12]}, r"\[arm\] pins: a GPIO is used twice"),
    ({"lower": [0.0, 0.1]}, r"\[arm\] joint elbow: lower \(0.1\) must be below upper"),
    ({"colour": "red"}, None),  # a key of the component's own: not the device's
    ({"min_pulse_us": 100}, r"\[arm\] min_pulse_us: must be >= 500"),
])
def test_servo_options_are_checked_naming_the_section(extra: dict[str, Any],
                                                      problem: str | None) -> None:
    options = _servo_options(type("E", (), {"options": {}})(), **extra)
    if problem is None:
        create_device("pigpio_servo", options, section="arm")
        return
    with pytest.raises(ValueError, match=problem):
        create_device("pigpio_servo", options, section="arm")


async def test_a_device_without_its_pigpiod_says_where_it_looked(tmp_path: Path) -> None:
    device = create_device("pigpio_servo", {"host": "127.0.0.1", "port": 1,
                                            "timeout_s": 0.5}, section="arm")
    with pytest.raises(DeviceError, match=r"\[arm\] pigpiod unreachable at 127.0.0.1:1"):
        await device.open()
    assert device.health()["status"] == "error"
