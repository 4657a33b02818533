# `arbiterd check` probing a lidar, `arbiterd status` against a running daemon.
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from sim.rplidar_emulator import RplidarEmulator
from tests.daemon_proc import REPO, DaemonProcess


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "daemon.cli", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=60)


def lidar_config(tmp_path: Path, port: Path) -> Path:
    path = tmp_path / "arbiterd.toml"
    path.write_text(f'[driver]\ntype = "mock"\n[lidar]\nenabled = true\nport = "{port}"\n')
    return path


def test_check_probes_the_lidar(tmp_path: Path) -> None:
    with RplidarEmulator(tmp_path / "rplidar").start() as lidar:
        result = run_cli("check", "--config", str(lidar_config(tmp_path, lidar.link)))
        assert result.returncode == 0, result.stderr
        assert "# lidar: A1M8" in result.stderr and "health ok" in result.stderr
        lidar.set_health(2, 0x8001, clears_on_reset=False)
        result = run_cli("check", "--config", str(lidar_config(tmp_path, lidar.link)))
        assert result.returncode == 69
        assert "reports a health error (code 0x8001)" in result.stderr


def test_check_reports_a_missing_lidar(tmp_path: Path) -> None:
    result = run_cli("check", "--config", str(lidar_config(tmp_path, tmp_path / "nothing")))
    assert result.returncode == 69
    assert f"hardware: [lidar] {tmp_path / 'nothing'}" in result.stderr


def test_status_summarises_a_running_daemon(tmp_path: Path) -> None:
    with DaemonProcess(tmp_path) as daemon:
        daemon.post("/api/cmd_vel", {"linear": {"x": 0.1}})
        result = run_cli("status", "--url", daemon.base_url)
        assert result.returncode == 0, result.stderr
        first = result.stdout.splitlines()[0]
        assert first.startswith("arbiterd ") and ": ok (ready), hardware mode, driver mock" in first
        assert "control" in result.stdout and "commands 1;" in result.stdout


def test_status_of_nothing_says_so(tmp_path: Path) -> None:
    result = run_cli("status", "--url", "http://127.0.0.1:9")
    assert result.returncode == 69 and "cannot reach" in result.stderr
