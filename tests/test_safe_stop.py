# `arbiterd safe-stop` as ExecStopPost= runs it: a fresh process zeroes motors left running.
from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import serial

from daemon.cli import _toml_value
from drivers import create_driver
from sim.arduino_emulator import ArduinoEmulator
from tests.daemon_proc import REPO, read_wheel_log, wait_for
from tests.rigs.l298n import pigpio_rig
from tests.rigs.pigpio import running_rig


def write_config(tmp_path: Path, driver: str, options: dict[str, Any]) -> Path:
    lines = ["[driver]", f'type = "{driver}"', f"[driver.{driver}]"]
    lines += [f"{key} = {_toml_value(value)}" for key, value in options.items()]
    path = tmp_path / "arbiterd.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def safe_stop(config: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "daemon.cli", "safe-stop", "--config",
                           str(config)], cwd=REPO, capture_output=True, text=True, timeout=60)


def turning(targets: tuple[float, float]) -> bool:
    return any(abs(t) > 1.0 for t in targets)


def test_safe_stop_mock_records_a_zero_command(tmp_path: Path) -> None:
    log = tmp_path / "wheels.log"
    result = safe_stop(write_config(tmp_path, "mock", {"log_file": str(log)}))
    assert result.returncode == 0, result.stderr
    assert read_wheel_log(log)[-1][1:] == (0.0, 0.0)
    assert "motors zeroed through the mock driver" in result.stdout


def test_safe_stop_serial_zeroes_a_running_arduino(tmp_path: Path) -> None:
    # a board without auto-reset on open and with a long auto-stop, so only safe-stop stops it
    with ArduinoEmulator(tmp_path / "arduino", reset_on_open=False, auto_stop_s=120) as board:
        with serial.Serial(str(board.link), 57600, timeout=1) as port:  # the "crashed" daemon
            port.write(b"m 20 20\r")
            assert port.readline().strip() == b"OK"
        wait_for(lambda: turning(board.motors.targets()), 5, "the wheels to turn")
        config = write_config(tmp_path, "serial", {"port": str(board.link),
                                                   "reset_wait_s": 0.05})
        result = safe_stop(config)
        assert result.returncode == 0, result.stderr
        assert board.motors.targets() == (0.0, 0.0)


async def test_safe_stop_pigpio_zeroes_pwm_left_on(tmp_path: Path) -> None:
    async with running_rig() as rig:
        crashed = create_driver("pigpio", rig.options, max_wheel_speed=40.0)
        await crashed.open()
        await crashed.set_wheel_speeds(10.0, 10.0)
        wait_for(lambda: turning(rig.observed_targets()), 5, "the wheels to turn")
        result = safe_stop(write_config(tmp_path, "pigpio", rig.options))
        assert result.returncode == 0, result.stderr
        assert rig.observed_targets() == (0.0, 0.0)
        await crashed.close()


async def test_safe_stop_l298n_through_pigpiod(tmp_path: Path) -> None:
    async with pigpio_rig() as rig:
        crashed = create_driver("l298n", rig.options, max_wheel_speed=40.0)
        await crashed.open()
        await crashed.set_wheel_speeds(10.0, 10.0)
        wait_for(lambda: turning(rig.observed_targets()), 5, "the wheels to turn")
        result = safe_stop(write_config(tmp_path, "l298n", rig.options))
        assert result.returncode == 0, result.stderr
        assert rig.observed_targets() == (0.0, 0.0)
        await crashed.close()


def test_safe_stop_reports_unreachable_hardware(tmp_path: Path) -> None:
    config = write_config(tmp_path, "serial", {"port": str(tmp_path / "no-such-tty"),
                                               "reset_wait_s": 0.0})
    result = safe_stop(config)
    assert result.returncode == 69
    assert "could not zero the motors" in result.stderr
