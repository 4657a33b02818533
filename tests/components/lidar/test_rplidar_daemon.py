# End to end: the real daemon streams from the emulated RPLIDAR and survives its faults.
from __future__ import annotations

import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from sim.rplidar_emulator import A1, RplidarEmulator
from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.net import http
from tests.support.wait import wait_for

# Runs `arbiterd run` through daemon.cli.main in a subprocess of this interpreter.
LAUNCH = "import sys; from daemon.cli import main; sys.exit(main(sys.argv[1:]))"


class LidarDaemon(DaemonSubprocess):
    def command(self) -> list[str]:
        return [sys.executable, "-c", LAUNCH, "run", "--config", str(self.config_path)]


class HealthWatcher:
    """Polls /api/health in the background: the daemon must answer throughout."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.failures: list[str] = []
        self.answers = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.1):
            try:
                status, _ = http("GET", self.url, timeout=2.0)
                self.answers += 1
                if status != 200:
                    self.failures.append(f"status {status}")
            except OSError as exc:
                self.failures.append(str(exc))

    def __enter__(self) -> HealthWatcher:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[tuple[RplidarEmulator, LidarDaemon]]:
    link = tmp_path / "rplidar"
    with RplidarEmulator(link, A1) as emulator:
        toml = (f"[driver]\ntype = \"mock\"\n[lidar]\nenabled = true\nport = \"{link}\"\n"
                "baudrate = 115200\nscan_mode = \"express\"\n")
        daemon = LidarDaemon(tmp_path, toml)
        with daemon:
            yield emulator, daemon


def lidar_health(daemon: DaemonSubprocess) -> dict[str, Any]:
    status, body = daemon.get("/api/health")
    assert status == 200, body
    lidar: dict[str, Any] = body["components"]["lidar"]
    return lidar


def more_revolutions(daemon: DaemonSubprocess, extra: int = 3, timeout: float = 10.0) -> None:
    target = lidar_health(daemon)["revolutions"] + extra
    wait_for(lambda: lidar_health(daemon)["revolutions"] >= target, f"{extra} more revolutions",
             within_s=timeout)


def test_daemon_streams_and_survives_garbage_stall_and_unplug(
        rig: tuple[RplidarEmulator, LidarDaemon]) -> None:
    emulator, daemon = rig
    with HealthWatcher(daemon.base_url + "/api/health") as watcher:
        wait_for(lambda: lidar_health(daemon)["revolutions"] >= 3, "first revolutions", within_s=15)
        lidar = lidar_health(daemon)
        assert lidar["status"] == "ok" and lidar["model"] == "A1M8" and lidar["mode"] == "Express"
        integrity = ("dropped_capsules", "dropped_nodes", "angle_misfits", "short_revolutions")
        assert all(lidar[key] == 0 for key in integrity), lidar
        status, scan = daemon.get("/api/scan")
        assert status == 200 and scan["frame_id"] == "laser" and len(scan["ranges"]) > 300

        emulator.inject_garbage(80)
        wait_for(lambda: lidar_health(daemon)["dropped_capsules"] >= 1, "a dropped capsule",
                 within_s=10)
        more_revolutions(daemon)
        assert lidar_health(daemon)["status"] == "ok"

        emulator.stall(3.0)
        wait_for(lambda: lidar_health(daemon)["stream_restarts"] >= 1, "a stream restart",
                 within_s=10)
        more_revolutions(daemon, timeout=15)
        assert lidar_health(daemon)["device_resets"] >= 1

        emulator.unplug()
        wait_for(lambda: lidar_health(daemon)["state"] == "disconnected", "disconnected",
                 within_s=10)
        assert lidar_health(daemon)["status"] == "degraded"
        emulator.replug()
        wait_for(lambda: lidar_health(daemon)["reconnects"] >= 1, "a reconnect", within_s=15)
        more_revolutions(daemon, timeout=15)
        lidar = lidar_health(daemon)
        assert lidar["status"] == "ok"
        assert lidar["dropped_capsules"] >= 1 and lidar["stream_restarts"] >= 1
    assert watcher.answers > 20 and watcher.failures == []
    status, info = daemon.get("/api/robot_info")
    assert status == 200
    assert info["lidar"]["model"] == "A1M8" and info["lidar"]["firmware"] == "1.29"
    assert daemon.stop() == 0
