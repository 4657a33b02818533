# RPLIDAR device manager: connect, probe, stream and recover forever in a reader thread.
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from base.retrylog import RetryLog
from sensors.rplidar import requests as p
from sensors.rplidar.assembler import Revolution, RevolutionAssembler
from sensors.rplidar.client import (
    LidarError,
    LidarTimeout,
    PortGone,
    RplidarClient,
    ScanPlan,
    SerialPort,
    UnknownScanMode,
    describe,
    open_serial,
)

log = logging.getLogger(__name__)

OpenPort = Callable[[str, int], SerialPort]


@dataclass
class ManagerConfig:
    port: str = "/dev/rplidar"
    baudrate: int = 115200
    scan_mode: str = "express"
    motor_pwm: int = 660
    request_timeout: float = 2.0
    revolution_timeout: float = 2.0
    banner_timeout: float = 2.0
    reconnect_min: float = 0.5
    reconnect_max: float = 10.0
    error_retry: float = 30.0


@dataclass
class LidarState:
    """What ``health()`` reports; written by the reader thread only."""

    state: str = "stopped"
    model: str | None = None
    firmware: str | None = None
    hardware: int | None = None
    serial: str | None = None
    mode: str | None = None
    device_health: str | None = None
    device_error_code: int | None = None
    sample_rate_hz: float = 0.0
    scan_rate_hz: float = 0.0
    revolutions: int = 0
    dropped_capsules: int = 0
    dropped_nodes: int = 0
    angle_misfits: int = 0
    short_revolutions: int = 0
    resyncs: int = 0
    reconnects: int = 0
    stream_restarts: int = 0
    device_resets: int = 0
    last_error: str | None = None
    last_revolution_mono: float | None = None


class _Recover(Exception):
    """The stream stalled: restart it without reopening the port."""


class LidarManager:
    """Keeps an RPLIDAR streaming; never lets an exception escape its thread.

    Recovery: no whole revolution for ``revolution_timeout`` → STOP, flush, RESET, banner,
    health, restart the scan; port errors → close and reopen with exponential back-off;
    device health 2 → one RESET, then report ``error`` and retry after ``error_retry``.
    """

    def __init__(self, config: ManagerConfig, on_revolution: Callable[[Revolution], None],
                 open_port: OpenPort = open_serial) -> None:
        self.config = config
        self.on_revolution = on_revolution
        self.open_port = open_port
        self.state = LidarState()
        self.info: p.DeviceInfo | None = None
        self.plan: ScanPlan | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._client: RplidarClient | None = None
        self._lost_once = False
        #: a missing or failing lidar: the reason once, then a short line now and then
        self._retries = RetryLog(log, "lidar disconnected")
        self._counted: dict[str, int] = {}  # parser counters already added to the state
        self._standing_error: str | None = None  # what last_error returns to on recovery

    # -- lifecycle

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="rplidar", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 3.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self.state.state = "stopped"

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def snapshot(self) -> dict[str, Any]:
        s = self.state
        fresh = (s.last_revolution_mono is not None
                 and time.monotonic() - s.last_revolution_mono < self.config.revolution_timeout)
        status = "ok" if s.state == "streaming" and fresh else "degraded"
        if s.state == "error":
            status = "error"
        return {"status": status, "state": s.state, "port": self.config.port,
                "model": s.model, "firmware": s.firmware, "hardware": s.hardware,
                "serial": s.serial, "mode": s.mode, "device_health": s.device_health,
                "device_error_code": s.device_error_code,
                "sample_rate_hz": round(s.sample_rate_hz, 1),
                "scan_rate_hz": round(s.scan_rate_hz, 2), "revolutions": s.revolutions,
                "dropped_capsules": s.dropped_capsules, "dropped_nodes": s.dropped_nodes,
                "angle_misfits": s.angle_misfits, "short_revolutions": s.short_revolutions,
                "resyncs": s.resyncs,
                "reconnects": s.reconnects, "reconnect_attempts": self._retries.attempts,
                "stream_restarts": s.stream_restarts,
                "device_resets": s.device_resets, "last_error": s.last_error}

    # -- the thread

    def _run(self) -> None:
        backoff = self.config.reconnect_min
        while not self._stop.is_set():
            try:
                self._session()
                backoff = self.config.reconnect_min
            except (PortGone, LidarError) as exc:
                self._disconnected(exc, backoff)
            except Exception as exc:  # never let the lidar take the daemon down
                log.exception("lidar session failed")
                self._disconnected(exc, backoff)
            finally:
                self._close()
            if self.state.state == "error":
                self._stop.wait(self.config.error_retry)
            else:
                self._stop.wait(backoff)
                backoff = min(backoff * 2, self.config.reconnect_max)

    def _disconnected(self, exc: BaseException, backoff: float) -> None:
        self._set_error("disconnected", exc)
        retry_s = self.config.error_retry if self.state.state == "error" else backoff
        self._retries.failed(str(self.state.last_error), retry_s)

    def _note(self, state: str, exc: BaseException) -> None:
        self._set_error(state, exc)
        log.warning("lidar %s: %s", state, self.state.last_error)

    def _set_error(self, state: str, exc: BaseException) -> None:
        if self.state.state != "error":
            self.state.state = state
        self.state.last_error = str(exc) or type(exc).__name__

    def _session(self) -> None:
        self.state.state = "connecting"
        port = self.open_port(self.config.port, self.config.baudrate)
        if self._lost_once:
            self.state.reconnects += 1
        self._lost_once = True
        client = self._client = RplidarClient(port, self.config.request_timeout)
        client.stop()
        info = self._probe(client)
        if not self._healthy(client):
            return
        self.plan = self._plan(client, info)
        self.state.mode = self.plan.name
        while not self._stop.is_set():
            try:
                self._stream(client, info, self.plan)
            except _Recover as why:
                self.state.stream_restarts += 1
                self._note("recovering", why)
                client.stop()
                self._reset(client)
                if not self._healthy(client):
                    return

    def _probe(self, client: RplidarClient) -> p.DeviceInfo:
        self.state.state = "probing"
        try:
            info = client.info()
        except LidarTimeout:
            self._reset(client)  # a wedged device: the SDK's "initial reset"
            info = client.info()
        self.info = info
        for key, value in describe(info).items():
            if hasattr(self.state, key):
                setattr(self.state, key, value)
        return info

    def _healthy(self, client: RplidarClient) -> bool:
        health = client.health()
        if health.status == 2:
            self._reset(client)
            health = client.health()
        self.state.device_health = health.status_name
        self.state.device_error_code = health.error_code
        if health.status == 2:
            self.state.state = "error"
            self.state.last_error = (f"device reports health error 0x{health.error_code:04X} "
                                     "after a reset; power-cycle the lidar")
            log.error("lidar %s", self.state.last_error)
            return False
        return True

    def _reset(self, client: RplidarClient) -> None:
        self.state.device_resets += 1
        client.reset(self.config.banner_timeout)

    def _plan(self, client: RplidarClient, info: p.DeviceInfo) -> ScanPlan:
        self._standing_error = None
        try:
            return client.plan(self.config.scan_mode, info)
        except UnknownScanMode as exc:
            self._standing_error = self.state.last_error = (
                f"{exc}; using the device's typical mode")
            log.error("lidar: %s", self.state.last_error)
            return client.plan("express", info)

    def _stream(self, client: RplidarClient, info: p.DeviceInfo, plan: ScanPlan) -> None:
        client.motor(info, True, self.config.motor_pwm)
        client.start_scan(plan)
        self.state.state = "streaming"
        self._retries.succeeded()
        assembler = RevolutionAssembler(sample_period=plan.us_per_sample * 1e-6)
        last_progress = time.monotonic()
        while not self._stop.is_set():
            events, t_arrival = client.stream()
            short = assembler.short
            now = time.monotonic()
            for rev in assembler.feed(events, t_arrival):
                last_progress = now
                self._publish(rev, now)
            self._count_errors(client, assembler, short)
            if now - last_progress > self.config.revolution_timeout:
                raise _Recover(f"no whole revolution for {self.config.revolution_timeout:.1f} s")

    def _count_errors(self, client: RplidarClient, assembler: RevolutionAssembler,
                      short_before: int) -> None:
        parser, s = client.parser, self.state
        counts = {"dropped_capsules": parser.dropped_capsules,
                  "dropped_nodes": parser.dropped_nodes, "resyncs": parser.resyncs,
                  "angle_misfits": parser.angle_misfits}
        for key, value in counts.items():
            setattr(s, key, getattr(s, key) + max(value - self._counted.get(key, 0), 0))
        self._counted = counts
        if assembler.short > short_before and assembler.last_short is not None:
            s.short_revolutions += assembler.short - short_before
            samples, expected = assembler.last_short
            s.last_error = (f"a revolution of {samples} samples was not published (a whole turn "
                            f"has about {expected:.0f}): bytes lost or damaged on the serial "
                            "line; check the cable if this keeps counting")

    def _publish(self, rev: Revolution, now: float) -> None:
        s = self.state
        s.revolutions += 1
        s.last_revolution_mono = now
        s.state = "streaming"
        s.last_error = self._standing_error  # recovered: only a standing condition remains
        if rev.scan_time > 0:
            rate, per_s = 1.0 / rev.scan_time, len(rev) / rev.scan_time
            s.scan_rate_hz = rate if not s.scan_rate_hz else 0.8 * s.scan_rate_hz + 0.2 * rate
            s.sample_rate_hz = (per_s if not s.sample_rate_hz
                                else 0.8 * s.sample_rate_hz + 0.2 * per_s)
        try:
            self.on_revolution(rev)
        except Exception:
            log.exception("lidar revolution consumer failed")

    def _close(self) -> None:
        client, self._client = self._client, None
        if client is None:
            return
        self._counted = {}
        try:
            client.write(p.stop())
            if self.info is not None:
                client.motor(self.info, False)
        except LidarError:
            pass
        try:
            client.port.close()
        except Exception:
            log.debug("closing the lidar port failed", exc_info=True)
