# The serial driver tells a late host from a silent board: a longer budget only while it is late.
from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from drivers import arduino_serial, host_load
from drivers.arduino_serial import SerialBridgeDriver
from tests.support.rigs import Rig, wired_rig
from tests.support.wait import eventually


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    with wired_rig("serial", tmp_path) as the_rig:
        yield the_rig


def driver(rig: Rig) -> SerialBridgeDriver:
    return SerialBridgeDriver(rig.options | {"timeout_s": 0.2, "late_host_timeout_s": 0.8},
                              max_wheel_speed=20.0)


def starve(rig: Rig, seconds: float) -> threading.Thread:
    """The emulated board's thread gets no CPU for ``seconds`` (as on a loaded host)."""
    def hold() -> None:
        with rig.emulator._lock:
            done.wait(seconds)

    done = threading.Event()
    thread = threading.Thread(target=hold, daemon=True)
    thread.start()
    return thread


async def next_poll(drv: SerialBridgeDriver) -> None:
    polls = drv.polls
    await eventually(lambda: drv.polls > polls or drv.fault is not None, "an encoder poll")


async def test_a_late_reply_on_a_busy_host_is_waited_for(
        rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(arduino_serial, "host_busy", lambda: "tasks waited for a CPU 60 %")
    drv = driver(rig)
    await drv.open()
    try:
        await next_poll(drv)
        starved = starve(rig, 0.45)  # longer than timeout_s, shorter than the late budget
        await asyncio.to_thread(starved.join)
        await next_poll(drv)
        await next_poll(drv)
        assert drv.fault is None
        health = drv.health()
        assert health["late_replies"] >= 1 and health["slowest_reply_ms"] > 200
        assert health["late_host_reason"] == "tasks waited for a CPU 60 %"
    finally:
        await drv.close()


async def test_a_silent_board_on_an_idle_host_faults_in_timeout_s(
        rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(arduino_serial, "host_busy", lambda: None)
    drv = driver(rig)
    await drv.open()
    try:
        await next_poll(drv)
        rig.emulator.mute = True
        await eventually(lambda: drv.fault is not None, "a fault")
        # at timeout_s; only a loop that itself woke late (a loaded test machine) waits longer
        assert "within 0.2 s" in str(drv.fault) or "event loop woke" in str(drv.fault)
        assert "CPU" not in str(drv.fault) and "load" not in str(drv.fault)
    finally:
        rig.emulator.mute = False
        await drv.close()


async def test_a_silent_board_on_a_busy_host_faults_after_the_late_budget(
        rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(arduino_serial, "host_busy", lambda: "load 3.0 per core")
    drv = driver(rig)
    await drv.open()
    try:
        await next_poll(drv)
        rig.emulator.mute = True
        await eventually(lambda: drv.fault is not None, "a fault", within_s=10)
        assert "the host late (load 3.0 per core)" in str(drv.fault)
        assert drv.late.extended >= 1
    finally:
        rig.emulator.mute = False
        await drv.close()


def test_host_busy_reads_the_cpu_pressure(tmp_path: Path) -> None:
    psi = tmp_path / "cpu"
    psi.write_text("some avg10=42.50 avg60=30.00 avg300=10.00 total=123\n"
                   "full avg10=0.00 avg60=0.00 avg300=0.00 total=0\n")
    assert host_load.host_busy(psi) == "tasks waited for a CPU 42 % of the last 10 s"
    psi.write_text("some avg10=2.00 avg60=1.00 avg300=1.00 total=1\n")
    assert host_load.host_busy(psi) is None


def test_without_pressure_the_load_average_decides(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(host_load.os, "cpu_count", lambda: 4)
    monkeypatch.setattr(host_load.os, "getloadavg", lambda: (8.0, 1.0, 1.0))
    assert host_load.host_busy(tmp_path / "absent") == "load 2.0 per core"
    monkeypatch.setattr(host_load.os, "getloadavg", lambda: (1.0, 1.0, 1.0))
    assert host_load.host_busy(tmp_path / "absent") is None
