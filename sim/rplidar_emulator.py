# RPLIDAR emulator on a pseudo-terminal: real wire protocol, ranges from a callable, fault switches.
from __future__ import annotations

import argparse
import contextlib
import os
import random
import select
import signal
import struct
import sys
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from sensors.rplidar import records, synth
from sensors.rplidar import requests as p
from sensors.rplidar.requests import Ans, Cmd, Conf

#: ranges_fn(angles_rad, t) -> metres; angles are the device's own (clockwise from its 0°),
#: t is the emulator clock (s). inf, NaN or <= 0 means no return.
RangesFn = Callable[[npt.NDArray[np.float64], float], npt.NDArray[np.float64]]

#: how often a streaming emulator sends what the rotor swept since (s): a UART's bytes arrive
#: in chunks anyway, and 50 wake-ups a second cost a tenth of 200
BATCH_S = 0.02
#: how long an idle emulator sleeps before it looks at its switches again (s); a request
#: wakes it at once
IDLE_S = 0.1
MAX_PENDING_OUT = 1 << 16


@dataclass(frozen=True)
class ModeSpec:
    name: str
    answer_type: int
    us_per_sample: float
    max_distance_m: float = 12.0


@dataclass(frozen=True)
class EmulatedModel:
    name: str
    model: int
    firmware: tuple[int, int]
    hardware: int
    modes: tuple[ModeSpec, ...]
    typical: int
    banner: bytes

    @property
    def has_conf(self) -> bool:
        return self.firmware >= (1, 24) or self.model >> 4 >= 4


A1 = EmulatedModel(
    "A1", 0x18, (1, 29), 7,
    (ModeSpec("Standard", Ans.NODE, 508.0), ModeSpec("Express", Ans.CAPSULE, 254.0)), 1,
    b"RP LIDAR System.\r\nFirmware Ver 1.29 - rtm, HW Ver 7\r\nModel: 18\r\n")
S2 = EmulatedModel(
    "S2", 0x71, (1, 2), 18,
    (ModeSpec("Standard", Ans.NODE, 200.0, 30.0),
     ModeSpec("DenseBoost", Ans.DENSE_CAPSULE, 31.25, 30.0)), 1,
    b"RP LIDAR System.\r\nFirmware Ver 1.02 - rc, HW Ver 18\r\nModel: 71\r\n")
MODELS = {"A1": A1, "S2": S2}


def room_ranges(angles_rad: npt.NDArray[np.float64], t: float) -> npt.NDArray[np.float64]:
    """Default world: the lidar 1 m from the left wall of a 4 m x 3 m room, a pillar ahead."""
    dx, dy = np.cos(angles_rad), -np.sin(angles_rad)  # device angles run clockwise
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(dx > 0, 3.0 / dx, np.where(dx < 0, -1.0 / dx, np.inf))
        ty = np.where(dy > 0, 1.5 / dy, np.where(dy < 0, -1.5 / dy, np.inf))
    walls = np.minimum(tx, ty)
    # pillar of radius 0.2 m at (1.5, 0.5)
    b = dx * 1.5 + dy * 0.5
    disc = b * b - (1.5**2 + 0.5**2 - 0.04)
    pillar = np.where((disc >= 0) & (b > 0), b - np.sqrt(np.maximum(disc, 0)), np.inf)
    result: npt.NDArray[np.float64] = np.minimum(walls, pillar)
    return result


@dataclass
class Faults:
    garbage: int = 0  # bytes of random junk to splice into the next stream batch
    junk_every: int = 0  # records between bursts of junk, about (0 = off)
    junk_max: int = 8  # longest burst, bytes
    drop: int = 0  # bytes to delete from the next stream batch
    stall_until: float = 0.0  # monotonic time until which no scan bytes are sent
    health: p.Health = field(default_factory=lambda: p.Health(0, 0))
    health_clears_on_reset: bool = True


@dataclass
class _Stream:
    mode: ModeSpec
    t0: float
    sent: int = 0  # samples generated so far
    sync_sent: bool = False


class RplidarEmulator:
    """An RPLIDAR behind a pty whose slave is reachable at ``link`` (a stable symlink).

    Runs in its own thread (``start``/``close``). ``unplug()`` closes the pty and removes the
    link; ``replug()`` creates a fresh pty behind the same link.
    """

    def __init__(self, link: str | Path, model: EmulatedModel = A1,
                 ranges_fn: RangesFn = room_ranges, rotation_hz: float = 10.0,
                 seed: int = 1) -> None:
        self.link = Path(link)
        self.model = model
        self.ranges_fn = ranges_fn
        self.rotation_hz = rotation_hz
        self.faults = Faults()
        self.commands: deque[tuple[float, int, bytes]] = deque(maxlen=1000)
        self.motor_pwm: int | None = None
        self.resets = 0
        self._rng = random.Random(seed)
        self._junk_in = -1  # stream bytes until the next junk burst (-1: not drawn yet)
        self._lock = threading.RLock()
        self._stream: _Stream | None = None
        self._rx = b""
        self._out = bytearray()
        self._banner_at: float | None = None
        self._master = self._slave = -1
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._t_start = time.monotonic()

    # -- lifecycle

    def start(self) -> RplidarEmulator:
        self._open_pty()
        self._thread = threading.Thread(target=self._run, name="rplidar-emulator", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stopping.set()
        if self._thread:
            self._thread.join(timeout=2.0)
        with self._lock:
            self._close_pty()

    def __enter__(self) -> RplidarEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def plugged(self) -> bool:
        return self._master >= 0

    @property
    def streaming(self) -> str | None:
        stream = self._stream
        return stream.mode.name if stream else None

    # -- fault switches

    def inject_garbage(self, count: int) -> None:
        with self._lock:
            self.faults.garbage += count

    def sprinkle_junk(self, every_records: int, max_bytes: int = 8) -> None:
        """From now on, 1..``max_bytes`` random bytes at a random place about every
        ``every_records`` records of the stream (a flaky cable); 0 stops it."""
        with self._lock:
            self.faults.junk_every, self.faults.junk_max = every_records, max_bytes
            self._junk_in = -1

    def drop_bytes(self, count: int) -> None:
        with self._lock:
            self.faults.drop += count

    def stall(self, seconds: float) -> None:
        with self._lock:
            self.faults.stall_until = time.monotonic() + seconds

    def set_health(self, status: int, error_code: int = 0, clears_on_reset: bool = True) -> None:
        with self._lock:
            self.faults.health = p.Health(status, error_code)
            self.faults.health_clears_on_reset = clears_on_reset
            if status == 2:
                self._stream = None  # protection stop

    def unplug(self) -> None:
        with self._lock:
            self._close_pty()
            self._stream = None

    def replug(self) -> None:
        with self._lock:
            self._open_pty()
            self._queue(self.model.banner)

    # -- pty

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._rx, self._out = b"", bytearray()
        tmp = self.link.with_name(self.link.name + ".tmp")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        tmp.symlink_to(os.ttyname(slave))
        os.replace(tmp, self.link)

    def _close_pty(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()
        for fd in (self._master, self._slave):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = -1

    # -- main loop

    def _run(self) -> None:
        while not self._stopping.is_set():
            master = self._master
            if master < 0:
                self._stopping.wait(BATCH_S)
                continue
            try:
                readable, _, _ = select.select([master], [], [], self._wait_s(time.monotonic()))
                with self._lock:
                    if master != self._master:
                        continue
                    if readable:
                        self._receive(os.read(master, 4096))
                    self._tick(time.monotonic())
                    self._flush_out()
            except OSError:
                self._stopping.wait(BATCH_S)  # pty closed under us (unplug); the next loop sees it

    def _wait_s(self, now: float) -> float:
        """How long nothing is due: the next batch while streaming (sooner while bytes wait
        to be written), the banner after a reset, else an idle look at the switches."""
        wait = BATCH_S if self._stream is not None or self._out else IDLE_S
        if self._banner_at is not None:
            wait = min(wait, max(0.0, self._banner_at - now))
        return wait

    def _receive(self, data: bytes) -> None:
        self._rx += data
        while self._rx:
            start = self._rx.find(b"\xa5")
            if start < 0:
                self._rx = b""
                return
            self._rx = self._rx[start:]
            if len(self._rx) < 2:
                return
            cmd = self._rx[1]
            size = 2 if not cmd & 0x80 else (4 + self._rx[2] if len(self._rx) >= 3 else 0)
            if size == 0 or len(self._rx) < size:
                return
            frame, self._rx = self._rx[:size], self._rx[size:]
            parsed = p.parse_request(frame)
            if parsed is None:
                continue
            self.commands.append((time.monotonic(), parsed[0], parsed[1]))
            self._handle(*parsed)

    def _handle(self, cmd: int, payload: bytes) -> None:
        handlers: dict[int, Callable[[bytes], None]] = {
            Cmd.STOP: self._on_stop, Cmd.RESET: self._on_reset, Cmd.GET_INFO: self._on_info,
            Cmd.GET_HEALTH: self._on_health, Cmd.GET_SAMPLERATE: self._on_samplerate,
            Cmd.GET_LIDAR_CONF: self._on_conf, Cmd.SCAN: self._on_scan,
            Cmd.FORCE_SCAN: self._on_scan, Cmd.EXPRESS_SCAN: self._on_express,
            Cmd.SET_MOTOR_PWM: self._on_motor, Cmd.HQ_MOTOR_SPEED_CTRL: self._on_motor,
            Cmd.GET_ACC_BOARD_FLAG: self._on_acc_flag,
        }
        handler = handlers.get(cmd)
        if handler is not None:
            handler(payload)

    def _reply(self, data_type: int, body: bytes) -> None:
        self._queue(p.Descriptor(len(body), False, data_type).encode() + body)

    def _queue(self, data: bytes) -> None:
        self._out += data
        if len(self._out) > MAX_PENDING_OUT:  # nobody reads: a UART does not wait either
            del self._out[:len(self._out) - MAX_PENDING_OUT]

    def _flush_out(self) -> None:
        if not self._out or self._master < 0:
            return
        try:
            written = os.write(self._master, bytes(self._out))
        except BlockingIOError:
            return
        del self._out[:written]

    # -- command handlers

    def _on_stop(self, _: bytes) -> None:
        self._stream = None

    def _on_reset(self, _: bytes) -> None:
        self._stream = None
        self.resets += 1
        self._out.clear()
        if self.faults.health_clears_on_reset:
            self.faults.health = p.Health(0, 0)
        self._banner_at = time.monotonic() + 0.005

    def _on_info(self, _: bytes) -> None:
        major, minor = self.model.firmware
        serial = bytes((0x5A ^ i) * 7 % 256 for i in range(16))
        self._reply(Ans.INFO, struct.pack("<BBBB", self.model.model, minor, major,
                                          self.model.hardware) + serial)

    def _on_health(self, _: bytes) -> None:
        health = self.faults.health
        self._reply(Ans.HEALTH, struct.pack("<BH", health.status, health.error_code))

    def _on_samplerate(self, _: bytes) -> None:
        std = next(m for m in self.model.modes if m.answer_type == Ans.NODE)
        fast = next((m for m in self.model.modes if m.answer_type != Ans.NODE), std)
        self._reply(Ans.SAMPLERATE, struct.pack("<HH", int(std.us_per_sample),
                                                int(fast.us_per_sample)))

    def _on_conf(self, payload: bytes) -> None:
        if not self.model.has_conf or len(payload) < 4:
            return
        conf_type = struct.unpack_from("<I", payload)[0]
        mode_id = struct.unpack_from("<H", payload, 4)[0] if len(payload) >= 6 else 0
        mode = self.model.modes[min(mode_id, len(self.model.modes) - 1)]
        values = {
            Conf.SCAN_MODE_COUNT: struct.pack("<H", len(self.model.modes)),
            Conf.SCAN_MODE_TYPICAL: struct.pack("<H", self.model.typical),
            Conf.SCAN_MODE_NAME: mode.name.encode() + b"\x00",
            Conf.SCAN_MODE_US_PER_SAMPLE: struct.pack("<I", int(mode.us_per_sample * 256)),
            Conf.SCAN_MODE_MAX_DISTANCE: struct.pack("<I", int(mode.max_distance_m * 256)),
            Conf.SCAN_MODE_ANS_TYPE: struct.pack("<B", mode.answer_type),
        }
        self._reply(Ans.LIDAR_CONF, struct.pack("<I", conf_type) + values.get(conf_type, b""))

    def _on_scan(self, _: bytes) -> None:
        mode = next(m for m in self.model.modes if m.answer_type == Ans.NODE)
        self._begin(mode)

    def _on_express(self, payload: bytes) -> None:
        working_mode = payload[0] if payload else 0
        if self.model.has_conf and working_mode < len(self.model.modes):
            mode = self.model.modes[working_mode]
        else:
            mode = next(m for m in self.model.modes if m.answer_type == Ans.CAPSULE)
        if working_mode == 0 and mode.answer_type == Ans.NODE:  # legacy express request
            mode = next((m for m in self.model.modes if m.answer_type == Ans.CAPSULE), mode)
        self._begin(mode)

    def _begin(self, mode: ModeSpec) -> None:
        if self.faults.health.status == 2:
            return  # protection stop: scans are refused until RESET
        self._queue(synth.STREAM_DESCRIPTORS[mode.answer_type].encode())
        self._stream = _Stream(mode, time.monotonic())

    def _on_motor(self, payload: bytes) -> None:
        self.motor_pwm = struct.unpack_from("<H", payload)[0] if len(payload) >= 2 else None

    def _on_acc_flag(self, _: bytes) -> None:
        self._reply(Ans.ACC_BOARD_FLAG, struct.pack("<I", 0))

    # -- streaming

    def _tick(self, now: float) -> None:
        if self._banner_at is not None and now >= self._banner_at:
            self._banner_at = None
            self._queue(self.model.banner)
        stream = self._stream
        if stream is None:
            return
        per_record = synth.SAMPLES_PER_CAPSULE.get(stream.mode.answer_type, 1)
        due = int((now - stream.t0) / (stream.mode.us_per_sample * 1e-6)) // per_record
        records_due = due - stream.sent // per_record
        if records_due <= 0:
            return
        batch = self._generate(stream, min(records_due, 400), per_record)
        if now < self.faults.stall_until:
            return  # the device is stuck: the samples are lost
        size = synth.STREAM_DESCRIPTORS[stream.mode.answer_type].length
        self._queue(self._apply_faults(self._sprinkle_junk(batch, size)))

    def _generate(self, stream: _Stream, count: int, per_record: int) -> bytes:
        first = stream.sent
        stream.sent += count * per_record
        period = stream.mode.us_per_sample * 1e-6
        if stream.mode.answer_type == Ans.NODE:
            k = np.arange(first, first + count, dtype=np.float64)
            return self._nodes(k, period)
        starts = np.arange(first, first + (count + 1) * per_record, per_record, dtype=np.float64)
        sync = np.zeros(count, dtype=bool)
        sync[0] = not stream.sync_sent
        stream.sync_sent = True
        return self._capsules(stream.mode, starts, period, sync)

    def _rotor_deg(self, k: npt.NDArray[np.float64], period: float) -> npt.NDArray[np.float64]:
        result: npt.NDArray[np.float64] = np.mod(k * period * self.rotation_hz * 360.0, 360.0)
        return result

    def _sense(self, angle_deg: npt.NDArray[np.float64], t: float,
               max_m: float) -> npt.NDArray[np.float64]:
        ranges = np.asarray(self.ranges_fn(np.deg2rad(angle_deg), t), dtype=np.float64)
        ok = np.isfinite(ranges) & (ranges > 0) & (ranges <= max_m)
        return np.where(ok, ranges * 1000.0, 0.0)

    def _nodes(self, k: npt.NDArray[np.float64], period: float) -> bytes:
        angle_q6 = np.rint(self._rotor_deg(k, period) * 64) % 23040
        previous = np.rint(self._rotor_deg(k - 1, period) * 64) % 23040
        start = angle_q6 < previous
        dist = np.rint(self._sense(angle_q6 / 64, self._now(), 16.0) * 4) / 4
        quality = np.where(dist > 0, 15, 0)
        return synth.encode_nodes(angle_q6 / 64, dist, quality, start)

    def _capsules(self, mode: ModeSpec, starts: npt.NDArray[np.float64], period: float,
                  sync: npt.NDArray[np.bool_]) -> bytes:
        start_q6 = (np.rint(self._rotor_deg(starts, period) * 64) % 23040).astype(np.int64)
        count, per = len(sync), synth.SAMPLES_PER_CAPSULE[mode.answer_type]
        t = self._now()
        if mode.answer_type == Ans.CAPSULE:
            # optical offsets of 6-7.9° (bit 5 set, like a real unit), varying slowly
            dtheta = 48 + (np.arange(count * per).reshape(count, per) // 8) % 16
            probe = synth.encode_legacy(start_q6, np.zeros((count + 1, per)),
                                        np.vstack([dtheta, dtheta[:1]]), np.r_[sync, False])
            angles = self._decoded_angles(probe, records.decode_legacy, count)
            dist = self._sense(angles, t, mode.max_distance_m).reshape(count, per)
            return synth.encode_legacy(start_q6[:-1], dist, dtheta, sync)
        probe = synth.encode_dense(start_q6, np.zeros((count + 1, per)), np.r_[sync, False])
        angles = self._decoded_angles(probe, records.decode_dense, count)
        dist = self._sense(angles, t, mode.max_distance_m).reshape(count, per)
        return synth.encode_dense(start_q6[:-1], dist, sync)

    @staticmethod
    def _decoded_angles(probe: bytes, decode: Callable[[records.U8, records.U8],
                                                       records.DecodedSamples],
                        count: int) -> npt.NDArray[np.float64]:
        """The exact angles a receiver will compute (capsule angles depend on the next start)."""
        caps = np.frombuffer(probe, dtype=np.uint8).reshape(count + 1, -1)
        return decode(caps[:-1], caps[1:]).angle_deg

    def _sprinkle_junk(self, batch: bytes, record_size: int) -> bytes:
        every = self.faults.junk_every * record_size
        if every <= 0:
            return batch
        if self._junk_in < 0:
            self._junk_in = self._rng.randint(every // 2, every)
        parts, last = [], 0
        while self._junk_in < len(batch):
            at = self._junk_in
            burst = self._rng.randint(1, self.faults.junk_max)
            parts += [batch[last:at], bytes(self._rng.randrange(256) for _ in range(burst))]
            last = at
            self._junk_in += self._rng.randint(3 * every // 4, 5 * every // 4)
        self._junk_in -= len(batch)
        parts.append(batch[last:])
        return b"".join(parts)

    def _apply_faults(self, batch: bytes) -> bytes:
        faults = self.faults
        if faults.drop and batch:
            data = bytearray(batch)
            for _ in range(min(faults.drop, len(data) - 1)):
                del data[self._rng.randrange(len(data))]
            batch, faults.drop = bytes(data), 0
        if faults.garbage:
            junk = bytes(self._rng.randrange(256) for _ in range(faults.garbage))
            at = self._rng.randrange(len(batch) + 1)
            batch, faults.garbage = batch[:at] + junk + batch[at:], 0
        return batch

    def _now(self) -> float:
        return time.monotonic() - self._t_start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="RPLIDAR emulator on a pseudo-terminal")
    parser.add_argument("--link", required=True, help="symlink path to create for the port")
    parser.add_argument("--model", choices=sorted(MODELS), default="A1")
    parser.add_argument("--rotation-hz", type=float, default=10.0)
    args = parser.parse_args(argv)
    emulator = RplidarEmulator(args.link, MODELS[args.model], rotation_hz=args.rotation_hz)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    with emulator:
        print(f"RPLIDAR {args.model} emulator: connect to {args.link}", flush=True)
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
