# `arbiterd safe-stop` as ExecStopPost= runs it: a fresh process zeroes motors left running.
from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

from tests.support.async_daemon_subprocess import driver_daemon_config
from tests.support.mock_wheel_log import read_wheel_log
from tests.support.net import free_port
from tests.support.paths import REPO
from tests.support.rigs import Rig
from tests.support.wait import wait_for


def write_config(tmp_path: Path, driver: str, options: dict[str, Any]) -> Path:
    return driver_daemon_config(tmp_path, driver, options, free_port())


def safe_stop(config: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "daemon.cli", "safe-stop", "--config",
                           str(config)], cwd=REPO, capture_output=True, text=True, timeout=60)


def turning(targets: tuple[float, float]) -> bool:
    return any(abs(t) > 1.0 for t in targets)


async def test_safe_stop_zeroes_wheels_a_dead_daemon_left_turning(rig: Rig,
                                                                  tmp_path: Path) -> None:
    cleanup = await rig.strand()
    try:
        wait_for(lambda: turning(rig.observed_targets()), "the wheels to turn")
        if rig.reachable_from_other_processes:
            result = safe_stop(write_config(tmp_path, rig.driver_name, rig.options))
            assert result.returncode == 0, result.stderr
        else:  # the emulator lives in this process only: the same path, without the process
            await rig.make_driver(40.0).safe_stop()
        assert rig.observed_targets() == (0.0, 0.0)
    finally:
        await cleanup()


def test_safe_stop_mock_records_a_zero_command(tmp_path: Path) -> None:
    log = tmp_path / "wheels.log"
    result = safe_stop(write_config(tmp_path, "mock", {"log_file": str(log)}))
    assert result.returncode == 0, result.stderr
    assert read_wheel_log(log)[-1][1:] == (0.0, 0.0)
    assert "motors zeroed through the mock driver" in result.stdout


def test_safe_stop_reports_unreachable_hardware(tmp_path: Path) -> None:
    config = write_config(tmp_path, "serial", {"port": str(tmp_path / "no-such-tty"),
                                               "reset_wait_s": 0.0})
    result = safe_stop(config)
    assert result.returncode == 69
    assert "could not zero the motors" in result.stderr
