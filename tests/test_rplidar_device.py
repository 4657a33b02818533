# Device manager and component against the emulator over a real pseudo-terminal.
from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from base.config import Config
from base.options import defaults
from daemon.bus import Bus
from daemon.components.lidar.component import create
from daemon.hooks import HookMap
from daemon.settings import RobotSettings
from daemon.telemetry import SCAN
from sensors.rplidar.assembler import Revolution
from sensors.rplidar.client import RplidarClient, open_serial
from sensors.rplidar.device import LidarManager, ManagerConfig
from sensors.rplidar.settings import LidarSettings
from sensors.scan import LaserScan
from sim.rplidar_emulator import A1, S2, EmulatedModel, RplidarEmulator
from tests.support.wait import Collector, wait_for


class Run:
    """An emulator plus a manager streaming from it."""

    def __init__(self, tmp_path: Path, model: EmulatedModel = A1, mode: str = "express",
                 ranges: Any = None) -> None:
        link = tmp_path / "rplidar"
        kwargs = {} if ranges is None else {"ranges_fn": ranges}
        self.emulator = RplidarEmulator(link, model, **kwargs).start()
        self.revolutions: Collector[Revolution] = Collector()
        config = ManagerConfig(port=str(link), scan_mode=mode, reconnect_min=0.05,
                               reconnect_max=0.3, error_retry=0.5, banner_timeout=0.5)
        self.manager = LidarManager(config, self.revolutions)

    def count(self) -> int:
        return self.revolutions.count()

    def health(self) -> dict[str, Any]:
        return self.manager.snapshot()

    def more_revolutions(self, extra: int = 3, timeout: float = 5.0) -> None:
        self.revolutions.wait(self.count() + extra, f"{extra} more revolutions", timeout)


@pytest.fixture
def run(tmp_path: Path) -> Iterator[Run]:
    r = Run(tmp_path)
    r.manager.start()
    yield r
    r.manager.stop()
    r.emulator.close()


def test_streams_whole_revolutions_and_reports_the_device(run: Run) -> None:
    run.more_revolutions(3)
    health = run.health()
    assert health["status"] == "ok" and health["state"] == "streaming"
    assert health["model"] == "A1M8" and health["firmware"] == "1.29"
    assert health["mode"] == "Express" and health["device_health"] == "ok"
    assert health["sample_rate_hz"] > 0 and health["scan_rate_hz"] > 0
    rev = run.revolutions.items()[-1]
    # express at 254 µs/sample and 10 Hz: about 394 samples, one full turn
    assert 300 < len(rev) < 500
    assert rev.angle_deg.min() < 10 and rev.angle_deg.max() > 350
    assert health["dropped_capsules"] == 0 and health["resyncs"] == 0


def poll(condition: Callable[[], bool], within_s: float) -> bool:
    """True as soon as ``condition`` holds, False after ``within_s`` without it."""
    try:
        wait_for(condition, "the condition", within_s=within_s)
    except AssertionError:
        return False
    return True


def test_garbage_and_dropped_bytes_are_survived_and_counted(run: Run) -> None:
    run.more_revolutions(2)
    run.emulator.inject_garbage(60)
    wait_for(lambda: run.health()["dropped_capsules"] >= 1, "a dropped capsule")
    # three bytes gone mid-capsule; the emulator sends in batches, and a cut that falls
    # between capsules loses nothing a capsule needs: cut again until one is dropped
    for _ in range(5):
        run.emulator.drop_bytes(3)
        if poll(lambda: run.health()["dropped_capsules"] >= 2, within_s=3.0):
            break
    assert run.health()["dropped_capsules"] >= 2, run.health()
    run.more_revolutions(3)
    assert run.health()["status"] == "ok"
    assert run.health()["stream_restarts"] == 0  # resync, not restart


def test_stalled_stream_is_restarted(run: Run) -> None:
    run.more_revolutions(2)
    run.emulator.stall(3.0)
    wait_for(lambda: run.health()["stream_restarts"] >= 1, "a restart", within_s=5)
    assert run.health()["status"] == "degraded"
    run.more_revolutions(3, timeout=8.0)
    health = run.health()
    assert health["status"] == "ok" and health["device_resets"] >= 1
    assert run.emulator.resets >= 1


def test_unplug_and_replug_reconnects(run: Run) -> None:
    run.more_revolutions(2)
    run.emulator.unplug()
    wait_for(lambda: run.health()["state"] == "disconnected", "disconnected")
    assert run.health()["status"] == "degraded"
    assert "cannot open" in (run.health()["last_error"] or "") or run.health()["last_error"]
    time.sleep(0.3)  # a few failed reopen attempts against a missing port
    run.emulator.replug()
    run.more_revolutions(3)
    health = run.health()
    assert health["reconnects"] >= 1 and health["status"] == "ok"


def test_health_error_cleared_by_one_reset(run: Run) -> None:
    run.more_revolutions(1)
    run.emulator.set_health(2, 0x0004, clears_on_reset=True)
    run.more_revolutions(3, timeout=8.0)  # watchdog: restart → RESET → healthy again
    assert run.health()["device_resets"] >= 1 and run.health()["device_health"] == "ok"


def test_persistent_health_error_is_reported_not_fatal(tmp_path: Path) -> None:
    r = Run(tmp_path)
    r.emulator.set_health(2, 0x0004, clears_on_reset=False)
    r.manager.start()
    try:
        wait_for(lambda: r.health()["state"] == "error", "error state")
        health = r.health()
        assert health["status"] == "error" and health["device_error_code"] == 4
        assert "0x0004" in health["last_error"]
        assert r.manager.running and r.count() == 0
        r.emulator.set_health(0, 0)
        r.more_revolutions(2, timeout=6.0)  # retried after error_retry
        assert r.health()["status"] == "ok"
    finally:
        r.manager.stop()
        r.emulator.close()


@pytest.mark.parametrize(("model", "mode", "expect"), [
    (A1, "standard", "Standard"), (S2, "express", "DenseBoost"), (S2, "denseboost", "DenseBoost"),
])
def test_modes(tmp_path: Path, model: EmulatedModel, mode: str, expect: str) -> None:
    r = Run(tmp_path, model, mode)
    r.manager.start()
    try:
        r.more_revolutions(2)
        assert r.health()["mode"] == expect
    finally:
        r.manager.stop()
        r.emulator.close()


def test_unknown_mode_falls_back_and_says_why(tmp_path: Path) -> None:
    r = Run(tmp_path, A1, "Sensitivity")
    r.manager.start()
    try:
        r.more_revolutions(1)
        error = r.health()["last_error"]
        assert "'Sensitivity'" in error and "Standard, Express" in error
    finally:
        r.manager.stop()
        r.emulator.close()


def test_missing_port_keeps_retrying(tmp_path: Path) -> None:
    config = ManagerConfig(port=str(tmp_path / "nothing"), reconnect_min=0.05, reconnect_max=0.1)
    manager = LidarManager(config, lambda rev: None)
    manager.start()
    try:
        wait_for(lambda: manager.snapshot()["state"] == "disconnected", "disconnected")
        assert "cannot open" in manager.snapshot()["last_error"]
        assert manager.running
    finally:
        manager.stop()
    assert not manager.running


def test_client_requests_against_the_emulator(tmp_path: Path) -> None:
    with RplidarEmulator(tmp_path / "lidar", A1):
        port = open_serial(str(tmp_path / "lidar"), 115200)
        try:
            client = RplidarClient(port, timeout=1.0)
            client.stop()
            banner = client.reset(banner_timeout=1.0)
            assert banner.startswith(b"RP LIDAR System")
            modes, typical = client.scan_modes()
            assert [m.name for m in modes] == ["Standard", "Express"] and typical == 1
            assert modes[1].us_per_sample == 254 and modes[1].answer_type == 0x82
            assert client.sample_rate().express_us == 254
        finally:
            port.close()


# ---------------------------------------------------------------- the daemon component


class FakeCtx:
    """What the lidar component's create() reads from a DaemonContext."""

    def __init__(self, port: str, enabled: bool = True) -> None:
        lidar = defaults(LidarSettings.OPTIONS) | {"enabled": enabled, "port": port,
                                          "baudrate": 115200, "scan_mode": "express",
                                          "angle_bins": 360, "frame_id": "lidar_link"}
        self.config = Config({"lidar": lidar, "robot": defaults(RobotSettings.OPTIONS)})
        self.bus = Bus()
        self.robot_info: HookMap[Any] = HookMap()
        self.mode = "sim"

    def settings(self, settings: type[LidarSettings]) -> LidarSettings:
        return self.config.get(settings)

    def add_robot_info(self, name: str, supplier: Any) -> Any:
        return self.robot_info.add(name, supplier)


def test_create_returns_none_when_disabled() -> None:
    assert create(FakeCtx("/dev/null", enabled=False)) is None  # type: ignore[arg-type]


async def test_component_publishes_scans_and_serves_them(tmp_path: Path) -> None:
    from daemon.web import ApiError

    with RplidarEmulator(tmp_path / "lidar", A1, ranges_fn=lambda a, t: np.full(len(a), 2.0)):
        ctx = FakeCtx(str(tmp_path / "lidar"))
        component = create(ctx)  # type: ignore[arg-type]
        assert component is not None and component.name == "lidar" and not component.core
        handler = {(r.method, r.path): r.handler for r in component.routes()}[
            ("GET", "/api/scan")]
        with pytest.raises(ApiError) as err:
            await handler(None)
        assert err.value.status == 404
        scans: list[LaserScan] = []
        two = asyncio.Event()

        def keep(scan: LaserScan) -> None:
            scans.append(scan)
            if len(scans) >= 2:
                two.set()

        ctx.bus.subscribe(SCAN, keep)
        await component.start()
        try:
            await asyncio.wait_for(two.wait(), 5.0)
            scan = scans[-1]
            assert scan.frame_id == "lidar_link" and len(scan.ranges) == 360
            finite = scan.ranges[np.isfinite(scan.ranges)]
            assert len(finite) > 300 and np.allclose(finite, 2.0)
            response = await handler(None)
            assert response.status == 200
            assert ctx.robot_info["lidar"]()["model"] == "A1M8"
            assert component.health().status == "ok"
        finally:
            await component.stop()
