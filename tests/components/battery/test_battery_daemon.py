# The battery in `run --sim`: the real INA driver on the emulated chip, /api/battery, the policy.
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from daemon.components.battery.charge import ChargeEstimator
from daemon.components.battery.settings import BatterySettings
from daemon.config import load_config
from daemon.probe import probe_hardware
from tests.support.in_process_daemon import in_process_daemon
from tests.support.wait import eventually


def battery_toml(device: str = "ina219", charge: float = 1.0, extra: str = "") -> str:
    # in_process_daemon's extra TOML follows its [sim] table
    return (f'battery_charge = {charge}\n[battery]\nenabled = true\ndevice = "{device}"\n'
            f'rate = 20.0\nsmoothing_s = 0.0\n{extra}\n')


async def get_battery(http: aiohttp.ClientSession, url: str) -> dict[str, Any]:
    async with http.get(f"{url}/api/battery") as answer:
        assert answer.status == 200
        body: dict[str, Any] = await answer.json()
        return body


@pytest.mark.parametrize("device", ["ina219", "ina226", "odrive_can", "sim"])
async def test_api_battery_reads_the_simulated_pack(tmp_path: Path, device: str) -> None:
    extra = 'shunt_ohms = 0.01\n' if device == "ina226" else ""
    async with in_process_daemon(tmp_path, battery_toml(device, 0.7, extra)) as robot, \
            aiohttp.ClientSession() as http:
        async def read() -> dict[str, Any] | None:
            body = await get_battery(http, robot.http_url)
            return body if body["percentage"] is not None else None

        body = await eventually(read, "a battery reading")
        pack = robot.ctx.sim.world.battery
        volts, amps = pack.measure()
        assert body["voltage"] == pytest.approx(volts, abs=0.05)
        assert body["current"] == pytest.approx(-amps, abs=0.01)  # negative: discharging
        assert body["percentage"] == pytest.approx(0.7, abs=0.02)
        assert body["status"] == "discharging" and body["level"] == "ok"
        assert robot.daemon.health()["components"]["battery"]["status"] == "ok"


async def test_a_dead_chip_is_an_error_with_no_number(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, battery_toml("ina219")) as robot, \
            aiohttp.ClientSession() as http:
        await eventually(lambda: robot.component("battery").latest, "a reading")
        robot.ctx.sim.device_emulators["battery"].answering = False

        async def failed() -> dict[str, Any] | None:
            body = await get_battery(http, robot.http_url)
            return body if body["problem"] else None

        body = await eventually(failed, "the read failure reported")
        assert body["percentage"] is None and body["voltage"] is None
        assert "no answer" in body["problem"] and "check its wiring" in body["problem"]
        health = robot.daemon.health()["components"]["battery"]
        assert health["status"] == "error" and "no answer" in health["problem"]
        robot.ctx.sim.device_emulators["battery"].answering = True
        await eventually(lambda: robot.component("battery").latest, "reading again")


async def test_very_low_refuses_goals_naming_the_charge(tmp_path: Path) -> None:
    toml = battery_toml("sim", 0.14) + "[navigation]\nenabled = true\n"
    async with in_process_daemon(tmp_path, toml) as robot, aiohttp.ClientSession() as http:
        battery = robot.component("battery")
        await eventually(lambda: battery.level == "very_low", "very low")
        async with http.post(f"{robot.http_url}/api/goal",
                             json={"x": 1.0, "y": 0.0}) as answer:
            assert answer.status == 409
            text = (await answer.json())["error"]
        assert "battery very low: 14 % (below 15 %)" in text
        health = robot.daemon.health()["components"]["battery"]
        assert health["status"] == "degraded" and "very low" in health["problem"]


async def test_critical_holds_the_wheels_and_closes_the_recording(tmp_path: Path) -> None:
    toml = battery_toml("sim", 0.5) + \
        f'[record]\nenabled = true\ndirectory = "{tmp_path / "rec"}"\n'
    async with in_process_daemon(tmp_path, toml) as robot, aiohttp.ClientSession() as http:
        battery = robot.component("battery")
        recorder = robot.component("recorder")
        await eventually(lambda: battery.latest, "a reading")
        await eventually(lambda: recorder.recorder.current, "a recording open")
        robot.ctx.sim.world.battery.set_soc(0.05)
        await eventually(lambda: battery.level == "critical", "critical")
        async with http.post(f"{robot.http_url}/api/cmd_vel",
                             json={"linear": {"x": 0.3}}) as answer:
            assert answer.status == 200
        control = robot.control
        await eventually(lambda: control.arbiter.decide(control.clock()).source == "battery",
                         "the hold wins over the client")
        await eventually(lambda: recorder.recorder.current is None, "the recording closed")
        assert robot.daemon.health()["components"]["battery"]["status"] == "error"


def test_the_level_needs_the_hysteresis_to_clear() -> None:
    config = load_config(None, sim=True)
    settings = dataclasses.replace(config.get(BatterySettings), smoothing_s=0.0)
    estimator = ChargeEstimator(settings)
    curve = [v * settings.cells for v in settings.cell_curve]

    def at(fraction: float, drawn: float = 0.5) -> str:
        index = fraction * 10  # the curve's steps are 10 %
        low, high = curve[int(index)], curve[min(int(index) + 1, 10)]
        volts = low + (high - low) * (index - int(index))
        return estimator.update(0.0, volts - drawn * settings.internal_resistance_ohm,
                                drawn).level

    assert at(0.19) == "low"
    assert at(0.21) == "low"  # not 3 % above 20 % yet
    assert at(0.235) == "ok"
    assert at(0.11) == "critical"
    assert at(0.13, drawn=-1.0) == "very_low"  # charging clears at once


async def test_check_probes_the_chip(tmp_path: Path) -> None:
    from sim.ina2xx_emulator import InaEmulator

    board = InaEmulator("ina219").start()
    try:
        path = tmp_path / "a.toml"
        path.write_text(f'[driver]\ntype = "mock"\n[battery]\nenabled = true\n'
                        f'bus = "{board.bus}"\n')
        assert await probe_hardware(load_config(path)) == []
        board.answering = False
        problems = await probe_hardware(load_config(path))
        assert len(problems) == 1 and "INA219 at 0x40" in problems[0]
        assert "no answer" in problems[0]
        board.answering = True
        board.chip.bus_disconnected = True
        problems = await probe_hardware(load_config(path))
        assert "no battery on VIN-/VBUS" in problems[0]
    finally:
        board.close()
