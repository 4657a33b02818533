# What the daemon's log says: time stamps outside the journal, a missing device once and then
# rarely, no warning for components still starting.
from __future__ import annotations

import io
import logging
import os
import re
from pathlib import Path
from typing import Any

import pytest

from base.retrylog import RetryLog
from daemon import app
from daemon.app import Daemon
from daemon.cli import setup_logging
from daemon.config import load_config
from daemon.health import Health
from sensors.rplidar.device import LidarManager, ManagerConfig
from tests.support.wait import wait_for

LONG = ("cannot open serial port /dev/arduino: /dev/arduino does not exist; serial devices "
        "present: none (is the board plugged in and powered?); the user running arbiterd needs "
        "the dialout group to open serial ports (sudo usermod -aG dialout $USER, then log in "
        "again)")


@pytest.fixture
def restore_logging() -> Any:
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)


def one_line(path: Path, env: dict[str, str], timestamps: bool = True) -> str:
    with path.open("w") as stream:
        setup_logging("info", timestamps, stream, env)
        logging.getLogger("arbiterd").info("hello")
    return path.read_text()


def test_lines_start_with_the_time_outside_the_journal(tmp_path: Path,
                                                        restore_logging: Any) -> None:
    line = one_line(tmp_path / "terminal", {})
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d{3} INFO arbiterd: hello\n", line)
    assert one_line(tmp_path / "quiet", {}, timestamps=False) == "INFO arbiterd: hello\n"


def test_the_journal_gets_priorities_and_no_time(tmp_path: Path, restore_logging: Any) -> None:
    journal = tmp_path / "journal"
    journal.touch()
    found = os.stat(journal)
    line = one_line(journal, {"JOURNAL_STREAM": f"{found.st_dev}:{found.st_ino}"})
    assert line == "<6>arbiterd: hello\n"
    # a terminal of a desktop session inherits JOURNAL_STREAM: its stderr is no journal
    inherited = one_line(tmp_path / "terminal",
                         {"JOURNAL_STREAM": f"{found.st_dev}:{found.st_ino}"})
    assert inherited.endswith(" INFO arbiterd: hello\n") and inherited[0].isdigit()


def test_a_failure_for_the_same_reason_is_logged_once_then_briefly_once_a_minute() -> None:
    now = [0.0]
    stream = io.StringIO()
    logger = logging.getLogger("test.retrylog")
    logger.addHandler(logging.StreamHandler(stream))
    logger.propagate = False
    retries = RetryLog(logger, "driver reconnect failed", clock=lambda: now[0])
    retries.known(f"serial driver not available: {LONG}")  # the fault line said it
    for _ in range(30):  # 58 s of retries every 2 s: nothing
        retries.failed(LONG, 2.0)
        now[0] += 2.0
    assert stream.getvalue() == ""
    retries.failed(LONG, 2.0)  # a minute on, one short line
    retries.failed(LONG, 2.0)
    assert stream.getvalue().splitlines() == [
        "driver reconnect failed: still failing, 31 attempts in 60 s (same reason); retrying "
        "every 2.0 s"]
    retries.failed("cannot open serial port /dev/arduino: permission denied", 2.0)
    assert stream.getvalue().splitlines()[-1] == (
        "driver reconnect failed: cannot open serial port /dev/arduino: permission denied; "
        "retrying in 2.0 s")
    assert retries.attempts == 1
    retries.succeeded()
    retries.failed(LONG, 0.5)
    assert stream.getvalue().splitlines()[-1].startswith(f"driver reconnect failed: {LONG}")
    assert all(len(line) < 120 for line in stream.getvalue().splitlines()[:2])


def test_a_missing_lidar_is_logged_once_however_often_it_is_tried(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    port = tmp_path / "rplidar"
    config = ManagerConfig(port=str(port), reconnect_min=0.001, reconnect_max=0.002)
    manager = LidarManager(config, lambda rev: None)
    with caplog.at_level(logging.WARNING, "sensors.rplidar.device"):
        manager.start()
        try:
            wait_for(lambda: manager.snapshot()["reconnect_attempts"] >= 20, "20 attempts")
        finally:
            manager.stop()
    lines = [r.getMessage() for r in caplog.records if str(port) in r.getMessage()]
    assert len(lines) == 1 and lines[0].startswith(f"lidar disconnected: cannot open {port}")


class Part:
    """A component reporting the health it is given."""

    def __init__(self, name: str, **health: Any) -> None:
        self.name, self.core, self.report = name, False, health

    def health(self) -> Health:
        return Health.of(self.report, "last_error", otherwise=str(self.report.get("state", "")))


def test_a_component_still_starting_is_no_warning_but_one_that_stays_degraded_is(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / "a.toml").write_text('[sim]\ndriver = "mock"\n')
    daemon = Daemon(load_config(tmp_path / "a.toml", sim=True, env={}))
    lidar = Part("lidar", status="degraded", state="connecting")
    daemon.components = [Part("control", status="ok"), lidar]  # type: ignore[list-item]

    def state_lines() -> list[tuple[str, str]]:
        lines = [(r.levelname, r.getMessage()) for r in caplog.records
                 if r.getMessage().startswith("state:")]
        caplog.clear()
        return lines

    with caplog.at_level(logging.INFO, "arbiterd"):
        daemon._update_state()  # just started: the lidar has not sent its first scan
        assert state_lines() == [("INFO", "state: degraded, sim mode, driver mock, simulated "
                                  "robot, mock emulator (starting: lidar degraded: connecting)")]
        daemon._update_state()
        assert state_lines() == []
        daemon.started_mono -= app.STARTUP_GRACE_S  # the grace is over: still degraded
        daemon._update_state()
        assert state_lines() == [("WARNING", "state: degraded, sim mode, driver mock, "
                                  "simulated robot, mock emulator (lidar degraded: connecting)")]
        daemon._update_state()
        lidar.report = {"status": "ok"}
        daemon._update_state()
        lidar.report = {"status": "degraded", "last_error": "lidar unplugged"}
        daemon._update_state()
        assert state_lines() == [
            ("INFO", "state: ready, sim mode, driver mock, simulated robot, mock emulator"),
            ("WARNING", "state: degraded, sim mode, driver mock, simulated robot, mock "
             "emulator (lidar degraded: lidar unplugged)")]
