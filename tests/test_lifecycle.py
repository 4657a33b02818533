# Supervised lifecycle against a real notify socket: READY, WATCHDOG, stall, SIGTERM, STOPPING.
from __future__ import annotations

import gc
import signal
import socket
import threading
import time
from pathlib import Path

from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.in_process_daemon import in_process_daemon
from tests.support.wait import wait_for


class NotifySocket:
    """A datagram socket standing in for systemd's NOTIFY_SOCKET; records every message."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0.2)
        self.messages: list[tuple[float, str]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            self.messages.append((time.monotonic(), data.decode()))

    def lines(self) -> list[str]:
        return [line for _, msg in list(self.messages) for line in msg.splitlines()]

    def times_of(self, line: str) -> list[float]:
        return [t for t, msg in list(self.messages) if line in msg.splitlines()]

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.sock.close()


def test_ready_watchdog_stall_and_sigterm(tmp_path: Path) -> None:
    notify = NotifySocket(tmp_path / "notify.sock")
    env = {"NOTIFY_SOCKET": str(notify.path), "WATCHDOG_USEC": "400000"}
    daemon = DaemonSubprocess(tmp_path, "[control]\nallow_fault_injection = true\n", env=env)
    try:
        with daemon:
            wait_for(lambda: "READY=1" in notify.lines(), "READY=1", within_s=10)
            assert any(line.startswith("STATUS=ready") for line in notify.lines())
            wait_for(lambda: len(notify.times_of("WATCHDOG=1")) >= 6, "watchdog pings", within_s=10)
            pings = notify.times_of("WATCHDOG=1")
            gaps = [b - a for a, b in zip(pings[-5:], pings[-4:], strict=False)]
            # WATCHDOG_USEC 400 ms -> one ping per ~200 ms (ticks are 20 ms apart)
            assert all(0.15 < gap < 0.4 for gap in gaps), gaps

            daemon.post("/api/cmd_vel", {"linear": {"x": 0.4}})
            stall_start = time.monotonic()
            status, body = daemon.post("/api/debug/stall", {"seconds": 1.5}, timeout=10)
            stall_end = time.monotonic()
            assert status == 200, body
            during = [t for t in notify.times_of("WATCHDOG=1")
                      if stall_start + 0.05 < t < stall_end - 0.05]
            assert during == [], "watchdog was pet while the event loop was stalled"
            wait_for(lambda: any(t > stall_end for t in notify.times_of("WATCHDOG=1")),
                     "pings to resume after the stall", within_s=5)

            status, _ = daemon.post("/api/cmd_vel", {"linear": {"x": 0.5}})
            assert status == 200
            wait_for(lambda: daemon.wheels() and daemon.wheels()[-1][1] > 1.0, "motion", within_s=5)
            code = daemon.stop(signal.SIGTERM)
        assert code == 0, daemon.log()
        assert "STOPPING=1" in notify.lines()
        _, left, right = daemon.wheels()[-1]
        assert (left, right) == (0.0, 0.0), "motors were not zeroed before exit"
        assert "shutting down: signal SIGTERM" in daemon.log()
    finally:
        notify.close()


def test_sigint_also_takes_the_shutdown_path(tmp_path: Path) -> None:
    with DaemonSubprocess(tmp_path) as daemon:
        daemon.post("/api/cmd_vel", {"linear": {"x": 0.3}})
        wait_for(lambda: daemon.wheels() and daemon.wheels()[-1][1] > 0, "motion", within_s=5)
        assert daemon.stop(signal.SIGINT) == 0
    assert daemon.wheels()[-1][1:] == (0.0, 0.0)
    assert "shutting down: signal SIGINT" in daemon.log()


def test_no_watchdog_pings_without_watchdog_usec(tmp_path: Path) -> None:
    notify = NotifySocket(tmp_path / "notify.sock")
    try:
        with DaemonSubprocess(tmp_path, env={"NOTIFY_SOCKET": str(notify.path)}) as daemon:
            wait_for(lambda: "READY=1" in notify.lines(), "READY=1", within_s=10)
            daemon.post("/api/cmd_vel", {"linear": {"x": 0.1}})  # some ticks pass meanwhile
            status, health = daemon.get("/api/health")
            assert status == 200 and health["components"]["control"]["status"] == "ok"
            assert "WATCHDOG=1" not in notify.lines()
    finally:
        notify.close()


async def test_the_start_up_heap_is_frozen_while_the_daemon_runs(tmp_path: Path) -> None:
    """Full collections must not walk what start-up built (35-70 ms pauses of the tick):
    it is frozen once the daemon is ready, and given back to the collector when it stops."""
    async with in_process_daemon(tmp_path) as robot:
        assert robot.daemon.state != "startup"
        assert gc.get_freeze_count() > 10_000
    assert gc.get_freeze_count() == 0
