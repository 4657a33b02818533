# The battery monitors' real drivers (INA219, INA226, an ODrive's DC bus) against their emulators.
from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from drivers import ina2xx_protocol as ina
from drivers.devices import DeviceError, create_device
from drivers.ina2xx import InaMonitor
from sim.battery import BatteryModel, BatterySpec, open_circuit_v, soc_of_voltage
from sim.ina2xx_emulator import InaEmulator
from sim.odrive_emulator import ODriveEmulator


@pytest.fixture(params=["ina219", "ina226"])
def board(request: pytest.FixtureRequest) -> Iterator[InaEmulator]:
    # the INA226's 81.92 mV range wants a smaller shunt for these currents
    shunt = 0.1 if request.param == "ina219" else 0.01
    emulator = InaEmulator(request.param, battery=BatteryModel(soc=0.8),
                           shunt_ohms=shunt).start()
    yield emulator
    emulator.close()


def monitor(board: InaEmulator, **options: object) -> InaMonitor:
    device = create_device(board.chip.chip.name.lower(),
                           {"bus": board.bus, "shunt_ohms": board.chip.shunt_ohms, **options},
                           section="battery")
    assert isinstance(device, InaMonitor)
    return device


async def test_it_reads_the_packs_voltage_and_current(board: InaEmulator) -> None:
    device = monitor(board)
    await device.open()
    board.battery.step(1.0, (10.0, 10.0), on_dock=False)  # 0.8 A + 0.6 A of motors
    volts, amps = board.battery.measure()
    reading = await device.read()
    assert reading["voltage"] == pytest.approx(volts, abs=2 * board.chip.chip.bus_lsb_v)
    assert reading["current"] == pytest.approx(amps, abs=0.003)
    assert reading["power"] == pytest.approx(volts * amps, rel=0.01)
    assert device.health()["status"] == "ok"
    await device.close()


async def test_charging_reads_as_a_negative_current(board: InaEmulator) -> None:
    device = monitor(board)
    await device.open()
    board.battery.step(1.0, (0.0, 0.0), on_dock=True)
    reading = await device.read()
    assert reading["current"] < -0.5  # flowing back into the pack
    await device.close()


async def test_a_missing_chip_says_check_the_wiring_and_address(board: InaEmulator) -> None:
    board.answering = False
    device = monitor(board)
    with pytest.raises(DeviceError, match=r"\[battery\] INA2\d\d at 0x40 on emulated:.*no "
                                          r"answer.*check its wiring.*address"):
        await device.open()
    assert device.health()["status"] == "error"


async def test_a_wrong_address_gets_no_answer(board: InaEmulator) -> None:
    device = monitor(board, address=0x41)
    with pytest.raises(DeviceError, match=r"at 0x41.*no answer"):
        await device.open()


async def test_a_stuck_bus_is_named_as_such_and_the_reading_fails(board: InaEmulator) -> None:
    device = monitor(board)
    await device.open()
    board.stuck = True
    with pytest.raises(DeviceError, match="the bus is stuck"):
        await device.read()
    health = device.health()
    assert health["status"] == "error" and "stuck" in health["fault"]
    board.stuck = False
    assert (await device.read())["voltage"] > 9.0
    assert device.health()["status"] == "ok"
    await device.close()


async def test_no_battery_on_the_bus_input_is_an_error_not_zero_volts(
        board: InaEmulator) -> None:
    device = monitor(board)
    await device.open()
    board.chip.bus_disconnected = True
    with pytest.raises(DeviceError, match=r"reads 0\.00 V: no battery on VIN-/VBUS"):
        await device.read()
    await device.close()


async def test_a_brown_out_reset_is_noticed_and_the_chip_recalibrated(
        board: InaEmulator) -> None:
    device = monitor(board)
    await device.open()
    with board._lock:
        board.chip.reset()  # calibration 0: the current register reads 0
    reading = await device.read()
    assert reading["current"] == pytest.approx(board.battery.measure()[1], abs=0.003)
    assert device.recalibrations == 1
    assert board.chip.calibration == device.calibration.cal
    await device.close()


async def test_a_current_beyond_the_shunts_range_is_refused(board: InaEmulator) -> None:
    device = monitor(board)
    await device.open()
    board.battery.step(1.0, (200.0, 200.0), on_dock=False)  # 12.8 A: beyond either range
    with pytest.raises(DeviceError, match="end of its range: the current is beyond "
                                          "max_current_a, or shunt_ohms is wrong"):
        await device.read()
    await device.close()


@pytest.mark.parametrize(("driver", "chip", "problem"), [
    ("ina226", "ina219", "not an INA226"),
    ("ina219", "ina226", "not the INA219's 0x399f: another chip answers there"),
])
async def test_the_wrong_chip_is_named(driver: str, chip: str, problem: str) -> None:
    emulator = InaEmulator(chip).start()
    try:
        device = create_device(driver, {"bus": emulator.bus}, section="battery")
        with pytest.raises(DeviceError, match=problem):
            await device.open()
    finally:
        emulator.close()


def test_a_shunt_and_current_beyond_the_chip_are_a_config_error() -> None:
    with pytest.raises(ValueError, match=r"\[battery\] shunt_ohms, max_current_a: 10 A "
                                         r"through 0.1 ohm drops 1000.0 mV"):
        create_device("ina219", {"shunt_ohms": 0.1, "max_current_a": 10.0}, section="battery")


def test_calibration_follows_the_datasheets() -> None:
    # CAL = trunc(0.04096 / (LSB * R)) with LSB = 3.2 A / 2^15 = 97.66 uA, R = 0.1 ohm
    cal = ina.calibrate(ina.INA219, 0.1, 3.2)
    assert cal.cal == 4194 and cal.current_lsb_a == pytest.approx(97.66e-6, rel=1e-3)
    assert cal.config == 0x3DDF  # 32 V, 320 mV, 8 samples of 12 bits, continuous
    # CAL = trunc(0.00512 / (LSB * R)) with LSB = 20 A / 2^15 = 610.4 uA, R = 2 mohm
    assert ina.calibrate(ina.INA226, 0.002, 20.0).cal == 4194


def test_the_battery_model_sags_under_load_and_charges_on_the_dock() -> None:
    battery = BatteryModel(BatterySpec(capacity_ah=1.0), soc=0.5)
    rest = open_circuit_v(0.5, 3)
    battery.step(60.0, (20.0, 20.0), on_dock=False)
    volts, amps = battery.measure()
    assert amps == pytest.approx(0.8 + 1.2)
    assert volts == pytest.approx(open_circuit_v(battery.soc, 3) - amps * 0.12)
    assert battery.soc == pytest.approx(0.5 - 2.0 / 60)
    assert soc_of_voltage(rest, 3) == pytest.approx(0.5)
    battery.step(60.0, (0.0, 0.0), on_dock=True)
    assert battery.measure()[1] == pytest.approx(-2.0)
    assert battery.soc > 0.5 - 2.0 / 60


async def test_the_odrives_dc_bus(tmp_path: Path) -> None:
    channel = f"battery-{uuid.uuid4().hex[:8]}"
    odrive = ODriveEmulator("virtual", channel, node_ids=(3, 4)).start()
    try:
        odrive.battery.step(1.0, (5.0, 5.0), on_dock=False)
        device = create_device("odrive_battery", {"interface": "virtual", "channel": channel,
                                                  "node_id": 3}, section="battery")
        await device.open()
        reading = await device.read()
        volts, amps = odrive.battery.measure()
        assert reading["voltage"] == pytest.approx(volts, abs=1e-4)
        assert reading["current"] == pytest.approx(amps, abs=1e-4)
        odrive.set_online(False)
        with pytest.raises(DeviceError, match="no answer to Get_Bus_Voltage_Current"):
            await device.read()
        assert device.health()["status"] == "error"
        await device.close()
    finally:
        odrive.stop()


async def test_no_odrive_on_the_bus_fails_the_open() -> None:
    device = create_device("odrive_battery", {"interface": "virtual",
                                              "channel": f"none-{uuid.uuid4().hex[:8]}",
                                              "timeout_s": 0.05}, section="battery")
    with pytest.raises(DeviceError, match=r"\[battery\] ODrive node 0 on virtual:.*no answer"):
        await device.open()
