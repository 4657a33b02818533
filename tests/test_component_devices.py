# A component that uses a device, end to end: `run --sim` starts its emulator, bad keys are refused.
from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import aiohttp
import pytest
from aiohttp import web

import daemon.app
import daemon.config
from base.config import Config, ConfigError, SectionSettings
from base.options import option
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, DeviceUse, Route
from daemon.config import load_config
from daemon.health import Health
from daemon.registry import COMPONENTS
from daemon.web import json_response
from drivers.devices import Actuator, create_device
from drivers.pigpio_servo import ServoSettings
from tests.support.in_process_daemon import in_process_daemon


@dataclass(frozen=True)
class WaverSettings(ServoSettings, SectionSettings, section="waver"):
    """The servo's keys and its own switch."""

    enabled: bool = option(True, "wave")


class Waver(BaseComponent):
    """Moves its servo to what POST /api/waver says."""

    name = "waver"

    def __init__(self, servo: Actuator) -> None:
        self.servo = servo

    async def start(self) -> None:
        await self.servo.open()

    async def stop(self) -> None:
        await self.servo.close()

    def health(self) -> Health:
        return Health.of(self.servo.health(), "fault")

    def routes(self) -> Sequence[Route]:
        return (Route("POST", "/api/waver", self.post, "drive"),)

    async def post(self, request: web.Request) -> web.Response:
        return json_response(await self.servo.write(await request.json()))


def create(ctx: DaemonContext) -> Waver | None:
    if not ctx.settings(WaverSettings).enabled:
        return None
    servo = create_device("pigpio_servo", ctx.config["waver"], section="waver")
    assert isinstance(servo, Actuator)
    return Waver(servo)


def uses(config: Config) -> list[DeviceUse]:
    enabled = config.get(WaverSettings).enabled
    return [DeviceUse("pigpio_servo", "waver")] if enabled else []


@pytest.fixture
def with_waver(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The component table with the waver before the HTTP server (as a real row would be)."""
    table = (*COMPONENTS[:-1], ComponentSpec("waver", create, WaverSettings, uses),
             COMPONENTS[-1])
    monkeypatch.setattr(daemon.app, "COMPONENTS", table)
    monkeypatch.setattr(daemon.config, "COMPONENTS", table)
    monkeypatch.setitem(daemon.config.SETTINGS, "waver", WaverSettings)
    monkeypatch.setitem(daemon.config.SECTIONS, "waver", WaverSettings.OPTIONS)
    yield


WAVER = '[waver]\njoints = ["wrist", "finger"]\npins = [16, 26]\nlower = [-1.0, 0.0]\n' \
        'upper = [1.0, 0.035]\n'


async def test_run_sim_starts_the_devices_emulator_and_the_component_drives_it(
        tmp_path: Path, with_waver: None) -> None:
    async with in_process_daemon(tmp_path, WAVER) as robot:
        runtime = robot.ctx.sim
        emulator = runtime.device_emulators["waver"]
        assert robot.ctx.config["waver"]["port"] == emulator.port  # pointed at the emulator
        assert robot.daemon.health()["components"]["waver"]["status"] == "ok"
        async with aiohttp.ClientSession() as http, http.post(
                f"{robot.http_url}/api/waver", json={"wrist": 0.0, "finger": 1.0}) as answer:
            assert answer.status == 200
            assert await answer.json() == {"wrist": 0.0, "finger": 0.035}
        pins = emulator.bank.pins
        assert (pins[16].servo_us, pins[26].servo_us) == (1500, 2500)
        workdir = runtime.workdir
    assert not workdir.exists()  # the simulator's files go with it


def test_device_keys_that_clash_are_a_configuration_error(tmp_path: Path,
                                                          with_waver: None) -> None:
    path = tmp_path / "arbiterd.toml"
    path.write_text(WAVER.replace("pins = [16, 26]", "pins = [16, 16]"))
    with pytest.raises(ConfigError) as err:
        load_config(path, sim=True)
    assert err.value.problems == [f"{path}: [waver] pins: a GPIO is used twice: [16, 16]"]


def test_a_disabled_component_asks_for_no_emulator(tmp_path: Path, with_waver: None) -> None:
    path = tmp_path / "arbiterd.toml"
    path.write_text("[waver]\nenabled = false\npins = [16, 16]\n")  # not built: not checked
    config = load_config(path, sim=True)
    assert [use for spec in daemon.app.COMPONENTS for use in spec.devices_used(config)] == []
