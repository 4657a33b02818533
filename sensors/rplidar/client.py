# Blocking RPLIDAR client over a serial port: requests, probing, mode choice, motor, streaming.
from __future__ import annotations

import errno
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

from base.ports import open_error
from sensors.rplidar import requests as p
from sensors.rplidar.requests import Ans, Conf
from sensors.rplidar.streams import Event, StreamParser

T = TypeVar("T")


class LidarError(Exception):
    """The lidar did not behave: timeout, bad reply, device-reported error."""


class LidarTimeout(LidarError):
    pass


class PortGone(LidarError):
    """The serial port failed or vanished (USB unplugged, pty closed)."""


class UnknownScanMode(LidarError):
    pass


class SerialPort(Protocol):
    """The part of ``serial.Serial`` the client uses (the hardware seam)."""

    in_waiting: int

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes) -> int | None: ...

    def reset_input_buffer(self) -> None: ...

    def close(self) -> None: ...


def open_serial(path: str, baudrate: int, timeout: float = 0.05) -> SerialPort:
    """Open ``path`` exclusively, with DTR deasserted from the start (an A1's motor spins with
    DTR low). A port another process has locked is refused, naming that process."""
    import serial  # pyserial

    port = serial.Serial()
    port.port, port.baudrate, port.timeout, port.write_timeout = path, baudrate, timeout, 1.0
    port.exclusive = True
    port.dtr = False
    try:
        port.open()
    except (serial.SerialException, OSError) as exc:
        raise PortGone(f"cannot open {path}: {open_error(path, exc)}") from exc
    return port


def set_dtr(port: SerialPort, asserted: bool) -> bool:
    """Set DTR; False when the port has no DTR line (a pseudo-terminal answers ENOTTY)."""
    try:
        port.dtr = asserted  # type: ignore[attr-defined]
    except OSError as exc:
        if exc.errno == errno.ENOTTY:
            return False
        raise PortGone(f"setting DTR failed: {exc}") from exc
    except AttributeError:
        return False
    return True


@dataclass(frozen=True)
class ScanMode:
    id: int
    name: str
    us_per_sample: float
    max_distance_m: float
    answer_type: int


@dataclass(frozen=True)
class ScanPlan:
    """What to send to start scanning: SCAN, or EXPRESS_SCAN with a working mode."""

    name: str
    express: bool
    working_mode: int
    answer_type: int
    us_per_sample: float
    max_distance_m: float

    def request(self) -> bytes:
        return p.express_scan(self.working_mode) if self.express else p.scan()


def has_lidar_conf(info: p.DeviceInfo) -> bool:
    """GET_LIDAR_CONF exists on firmware >= 1.24 and on every C/S/T model."""
    return info.firmware_version >= (1, 24) or info.model >> 4 >= 4


def choose_plan(requested: str, info: p.DeviceInfo, modes: list[ScanMode] | None,
                typical: int | None, rate: p.SampleRate | None) -> ScanPlan:
    """Pick the scan for ``requested`` ("standard", "express" or a device mode name)."""
    wanted = requested.strip().lower()
    std_us = float(rate.standard_us) if rate else 500.0
    if modes:
        by_name = {m.name.lower(): m for m in modes}
        if wanted == "standard":
            mode = by_name.get("standard") or next(
                (m for m in modes if m.answer_type == Ans.NODE), None)
            if mode is None:
                return ScanPlan("Standard", False, 0, Ans.NODE, std_us, 0.0)
        elif wanted == "express":
            mode = by_name.get("express") or next((m for m in modes if m.id == typical), modes[0])
        elif wanted in by_name:
            mode = by_name[wanted]
        else:
            names = ", ".join(m.name for m in modes)
            raise UnknownScanMode(f"scan mode {requested!r} is not offered by this device; "
                                  f"it offers: {names} (or standard/express)")
        express = mode.answer_type != Ans.NODE
        return ScanPlan(mode.name, express, mode.id, mode.answer_type, mode.us_per_sample,
                        mode.max_distance_m)
    if wanted not in ("standard", "express"):
        raise UnknownScanMode(f"scan mode {requested!r} needs GET_LIDAR_CONF (firmware >= 1.24); "
                              "this device only has standard/express")
    if wanted == "express" and info.firmware_version >= (1, 17):
        exp_us = float(rate.express_us) if rate else 250.0
        return ScanPlan("Express", True, 0, Ans.CAPSULE, exp_us, 0.0)
    return ScanPlan("Standard", False, 0, Ans.NODE, std_us, 0.0)


class RplidarClient:
    """Request/response and streaming over a :class:`SerialPort`; every wait is bounded."""

    def __init__(self, port: SerialPort, timeout: float = 2.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.port = port
        self.timeout = timeout
        self.parser = StreamParser()
        self._clock = clock
        self._pending: list[Event] = []

    # -- raw I/O

    def write(self, frame: bytes) -> None:
        try:
            self.port.write(frame)
        except Exception as exc:  # pyserial raises SerialException/OSError/termios.error
            raise PortGone(f"write failed: {exc}") from exc

    def read_chunk(self) -> bytes:
        """Whatever arrived (waits up to the port timeout for the first byte)."""
        try:
            data = self.port.read(max(1, self.port.in_waiting))
            more = self.port.in_waiting
            return data + self.port.read(more) if more else data
        except Exception as exc:
            raise PortGone(f"read failed: {exc}") from exc

    def flush(self) -> None:
        try:
            self.port.reset_input_buffer()
        except Exception as exc:
            raise PortGone(f"flush failed: {exc}") from exc
        self.parser.reset()
        self._pending.clear()

    # -- requests

    def request(self, frame: bytes, want: type[T], timeout: float | None = None) -> T:
        """Send ``frame`` and wait for the first reply event of type ``want``."""
        self._pending.clear()
        self.parser.reset()
        self.write(frame)
        deadline = self._clock() + (self.timeout if timeout is None else timeout)
        while self._clock() < deadline:
            for event in self.parser.feed(self.read_chunk()):
                if isinstance(event, want):
                    return event
        raise LidarTimeout(f"no {want.__name__} reply within "
                           f"{self.timeout if timeout is None else timeout:.1f} s")

    def stop(self) -> None:
        """STOP, let the stream drain (the SDK waits 100 ms), then discard what is buffered."""
        self.write(p.stop())
        time.sleep(0.1)
        self.flush()

    def reset(self, banner_timeout: float = 2.0, quiet: float = 0.1) -> bytes:
        """RESET and wait for the power-up banner to finish (or ``banner_timeout``)."""
        self.write(p.reset())
        banner = b""
        deadline = self._clock() + banner_timeout
        last = self._clock()
        while self._clock() < deadline:
            data = self.read_chunk()
            now = self._clock()
            if data:
                banner, last = banner + data, now
            elif banner and now - last >= quiet:
                break
        self.flush()
        return banner

    def info(self) -> p.DeviceInfo:
        return self.request(p.get_info(), p.DeviceInfo)

    def health(self) -> p.Health:
        return self.request(p.get_health(), p.Health)

    def sample_rate(self) -> p.SampleRate:
        return self.request(p.get_samplerate(), p.SampleRate)

    def conf(self, conf_type: int, mode: int | None = None) -> p.LidarConf:
        reply = self.request(p.get_lidar_conf(conf_type, mode), p.LidarConf)
        if reply.conf_type != conf_type:
            raise LidarError(f"LIDAR_CONF reply for type 0x{reply.conf_type:02X}, "
                             f"asked 0x{conf_type:02X}")
        return reply

    def scan_modes(self) -> tuple[list[ScanMode], int]:
        """The device's scan-mode table and its typical mode."""
        count = self.conf(Conf.SCAN_MODE_COUNT).as_int() & 0xFFFF
        modes = []
        for mode in range(count):
            name = self.conf(Conf.SCAN_MODE_NAME, mode).as_name()
            us = self.conf(Conf.SCAN_MODE_US_PER_SAMPLE, mode).as_int() / 256.0
            dist = (self.conf(Conf.SCAN_MODE_MAX_DISTANCE, mode).as_int() >> 8) * 1.0
            answer = self.conf(Conf.SCAN_MODE_ANS_TYPE, mode).as_int() & 0xFF
            modes.append(ScanMode(mode, name, us, dist, answer))
        typical = self.conf(Conf.SCAN_MODE_TYPICAL).as_int() & 0xFFFF
        return modes, typical

    def plan(self, requested: str, info: p.DeviceInfo) -> ScanPlan:
        rate = self._optional(self.sample_rate) if info.firmware_version >= (1, 17) else None
        modes, typical = (self.scan_modes() if has_lidar_conf(info) else (None, None))
        return choose_plan(requested, info, modes, typical, rate)

    def _optional(self, call: Callable[[], T]) -> T | None:
        try:
            return call()
        except LidarTimeout:
            return None

    # -- motor and streaming

    def motor(self, info: p.DeviceInfo, on: bool, pwm: int = 660) -> str:
        """Spin or stop the motor the way this model family wants; returns the method used."""
        major = info.model >> 4
        if major == 1:
            set_dtr(self.port, not on)
            return "dtr"
        if 2 <= major <= 5:
            flag = self._optional(lambda: self.request(p.get_acc_board_flag(), p.AccBoardFlag,
                                                       timeout=0.5))
            if (flag is not None and flag.has_pwm) or (flag is None and major <= 3):
                self.write(p.set_motor_pwm(pwm if on else 0))
                return "pwm"
        return "automatic"

    def start_scan(self, plan: ScanPlan) -> None:
        self.flush()
        self.write(plan.request())

    def stream(self) -> tuple[list[Event], float]:
        """One read: the parsed events and the wall-clock arrival time."""
        data = self.read_chunk()
        return (self.parser.feed(data) if data else []), time.time()


def describe(info: p.DeviceInfo) -> dict[str, Any]:
    return {"model": info.model_name, "model_id": info.model, "firmware": info.firmware,
            "hardware": info.hardware, "serial": info.serial}
