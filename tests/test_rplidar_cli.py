# `arbiterd lidar` CLI as a subprocess against the emulator on a pty.
from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from sim.rplidar_emulator import A1, S2, EmulatedModel, RplidarEmulator

ROOT = Path(__file__).resolve().parents[1]


def world(angles_rad: np.ndarray, t: float) -> np.ndarray:
    """A wobbly room with a no-return sector between 100° and 110° (device angles)."""
    ranges = 1.5 + 0.5 * np.sin(3 * angles_rad) + 0.3 * np.cos(angles_rad)
    deg = np.rad2deg(angles_rad)
    return np.where((deg >= 100) & (deg <= 110), np.inf, ranges)


def cli(*args: str, timeout: float = 20.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "sensors.rplidar.cli", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout, check=False)


@pytest.fixture
def lidar(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[tuple[RplidarEmulator, str]]:
    model: EmulatedModel = getattr(request, "param", A1)
    link = tmp_path / "rplidar"
    with RplidarEmulator(link, model, ranges_fn=world) as emulator:
        yield emulator, str(link)


@pytest.mark.parametrize(("mode", "quantum_m", "quality"), [
    ("express", 0.0005, 47),  # legacy capsules carry whole millimetres
    ("standard", 0.000125, 15),  # standard nodes carry quarter millimetres
])
def test_scan_json_ranges_match_what_the_emulator_was_given(
        lidar: tuple[RplidarEmulator, str], mode: str, quantum_m: float, quality: int) -> None:
    _, port = lidar
    done = cli("scan", "--port", port, "--mode", mode, "--revolutions", "3", "--json")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.strip().splitlines()
    assert len(lines) == 3
    for line in lines:
        rev = json.loads(line)
        assert set(rev) == {"t", "angles_deg", "ranges_m", "quality"}
        angles = np.array(rev["angles_deg"])
        assert len(angles) > 150 and angles.min() < 5 and angles.max() > 355
        expected = world(np.deg2rad(angles), 0.0)
        missing = np.array([r is None for r in rev["ranges_m"]])
        assert np.array_equal(missing, ~np.isfinite(expected))
        assert missing.any()
        got = np.array([r for r in rev["ranges_m"] if r is not None])
        assert np.all(np.abs(got - expected[~missing]) <= quantum_m + 1e-9)
        assert set(np.array(rev["quality"])[~missing].tolist()) == {quality}


@pytest.mark.parametrize("lidar", [S2], indirect=True)
def test_scan_dense_on_an_s2(lidar: tuple[RplidarEmulator, str]) -> None:
    _, port = lidar
    done = cli("scan", "--port", port, "--baud", "1000000", "--mode", "DenseBoost", "--json")
    assert done.returncode == 0, done.stderr
    rev = json.loads(done.stdout)
    angles = np.array(rev["angles_deg"])
    expected = world(np.deg2rad(angles), 0.0)
    got = np.array([np.inf if r is None else r for r in rev["ranges_m"]])
    assert len(angles) > 3000
    finite = np.isfinite(expected)
    assert np.array_equal(np.isfinite(got), finite)
    assert np.all(np.abs(got[finite] - expected[finite]) <= 0.0005 + 1e-9)


def test_info_and_health(lidar: tuple[RplidarEmulator, str]) -> None:
    emulator, port = lidar
    done = cli("info", "--port", port, "--json")
    assert done.returncode == 0, done.stderr
    info = json.loads(done.stdout)
    assert info["model"] == "A1M8" and info["firmware"] == "1.29" and info["hardware"] == 7
    assert [m["name"] for m in info["scan_modes"]] == ["Standard", "Express"]
    human = cli("health", "--port", port)
    assert human.returncode == 0 and "health ok" in human.stdout
    emulator.set_health(2, 0x0004, clears_on_reset=False)
    bad = cli("health", "--port", port, "--json")
    assert bad.returncode == 69
    assert json.loads(bad.stdout) == {"status": "error", "error_code": 4}


def test_errors_have_clear_messages_and_exit_codes(lidar: tuple[RplidarEmulator, str],
                                                   tmp_path: Path) -> None:
    _, port = lidar
    unknown = cli("scan", "--port", port, "--mode", "Sensitivity")
    assert unknown.returncode == 2
    assert "'Sensitivity' is not offered" in unknown.stderr
    assert "Standard, Express" in unknown.stderr
    missing = cli("info", "--port", str(tmp_path / "absent"))
    assert missing.returncode == 69 and "cannot open" in missing.stderr


def test_silent_port_is_hardware_unavailable(tmp_path: Path) -> None:
    import os

    master, slave = os.openpty()  # a port where nothing answers
    try:
        done = cli("info", "--port", os.ttyname(slave), timeout=30)
        assert done.returncode == 69
        assert "no answer" in done.stderr and "baud" in done.stderr
    finally:
        os.close(master)
        os.close(slave)


def test_standalone_emulator_process(tmp_path: Path) -> None:
    import signal

    link = tmp_path / "lidar"
    proc = subprocess.Popen([sys.executable, "-m", "sim.rplidar_emulator", "--link", str(link),
                             "--model", "S2"], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert f"connect to {link}" in proc.stdout.readline()
        done = cli("info", "--port", str(link), "--json")
        assert done.returncode == 0, done.stderr
        assert json.loads(done.stdout)["model"] == "S2M1"
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0
    assert not link.exists()
