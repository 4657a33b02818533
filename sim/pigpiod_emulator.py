# A pigpiod emulator: the pigpio socket protocol over TCP, L298N bridges driving a MotorPair.
from __future__ import annotations

import argparse
import contextlib
import signal
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, cast

from drivers.pigpio_protocol import (
    HARDWARE_DUTY_FULL,
    HARDWARE_PWM_CHANNEL,
    MODE_INPUT,
    MODE_OUTPUT,
    PI4B_REVISION,
    PUD_OFF,
    PUD_UP,
)
from drivers.quadrature import quadrature_levels
from sim.motor_model import MotorPair, WheelMotor
from sim.pigpio_script import ScriptHost

# -- wire format (pure: no I/O) -------------------------------------------------------------------

REQUEST = struct.Struct("<IIII")  # cmd, p1, p2, p3 (p3 = number of extension bytes that follow)
REPLY = struct.Struct("<IIII")  # cmd, p1, p2, result (signed, as uint32)
REPORT = struct.Struct("<HHII")  # seqno, flags, tick, level (bank 1)

CMD_MODES, CMD_MODEG, CMD_PUD, CMD_READ, CMD_WRITE = 0, 1, 2, 3, 4
CMD_PWM, CMD_PRS, CMD_PFS, CMD_SERVO, CMD_WDOG = 5, 6, 7, 8, 9
CMD_BR1, CMD_BR2, CMD_BC1, CMD_BC2, CMD_BS1, CMD_BS2 = 10, 11, 12, 13, 14, 15
CMD_TICK, CMD_HWVER, CMD_NO, CMD_NB, CMD_NP, CMD_NC = 16, 17, 18, 19, 20, 21
CMD_PRG, CMD_PFG, CMD_PRRG, CMD_PIGPV = 22, 23, 24, 26
CMD_GDC, CMD_GPW, CMD_HP, CMD_FG, CMD_FN, CMD_NOIB = 83, 84, 86, 97, 98, 99
CMD_PROC, CMD_PROCD, CMD_PROCR, CMD_PROCS, CMD_PROCP, CMD_PROCU = 38, 39, 40, 41, 45, 117

PI_BAD_USER_GPIO, PI_BAD_GPIO, PI_BAD_MODE, PI_BAD_LEVEL, PI_BAD_PUD = -2, -3, -4, -5, -6
PI_BAD_PULSEWIDTH, PI_BAD_DUTYCYCLE, PI_BAD_WDOG_TIMEOUT, PI_BAD_DUTYRANGE = -7, -8, -15, -21
PI_NO_HANDLE, PI_BAD_HANDLE, PI_UNKNOWN_COMMAND = -24, -25, -88
PI_NOT_HPWM_GPIO, PI_BAD_HPWM_FREQ, PI_BAD_HPWM_DUTY, PI_BAD_FILTER = -95, -96, -97, -125

PIGPIO_VERSION = 79
MAX_NOTIFY_HANDLES = 32
# set_PWM_frequency rounds to these at the default 5 us sample rate.
PWM_FREQUENCIES = (8000, 4000, 2000, 1600, 1000, 800, 500, 400, 320, 250, 200, 160, 100, 80, 50,
                   40, 20, 10)
FLAG_KEEPALIVE = 0x40


@dataclass(frozen=True)
class Request:
    """One decoded 16-byte command header."""

    cmd: int
    p1: int
    p2: int
    p3: int


def decode_request(header: bytes) -> Request:
    """Decode a 16-byte request header; raise ValueError naming the problem."""
    if len(header) != REQUEST.size:
        raise ValueError(f"request header must be {REQUEST.size} bytes, got {len(header)}")
    return Request(*REQUEST.unpack(header))


def encode_reply(req: Request, result: int) -> bytes:
    """The 16-byte reply: the request's cmd, p1, p2 and the (possibly negative) result."""
    return REPLY.pack(req.cmd, req.p1, req.p2, result & 0xFFFFFFFF)


def encode_report(seqno: int, flags: int, tick: int, level: int) -> bytes:
    """One 12-byte notification record."""
    return REPORT.pack(seqno & 0xFFFF, flags & 0xFFFF, tick & 0xFFFFFFFF, level & 0xFFFFFFFF)


def nearest_pwm_frequency(hz: int) -> int:
    """The frequency pigpiod actually sets for a DMA PWM request of ``hz``."""
    return min(PWM_FREQUENCIES, key=lambda f: (abs(f - hz), -f))


# -- the hardware behind the pins -----------------------------------------------------------------


@dataclass(frozen=True)
class HBridge:
    """One L298N channel: IN1, IN2 and an optional EN pin (``None`` = jumpered high).

    The average motor voltage is ``EN * (IN1 - IN2)`` with each pin's PWM duty as its level.
    ``reversed`` models a motor wired (or mounted) so that IN1 drives the wheel backward.
    """

    in1: int
    in2: int
    en: int | None = None
    reversed: bool = False

    def duty(self, level_of: Callable[[int], float]) -> float:
        enable = 1.0 if self.en is None else level_of(self.en)
        value = enable * (level_of(self.in1) - level_of(self.in2))
        return -value if self.reversed else value

    def pins(self) -> tuple[int, ...]:
        return (self.in1, self.in2) if self.en is None else (self.in1, self.in2, self.en)


@dataclass(frozen=True)
class Wiring:
    """What is connected to the emulated Pi: two bridges and optional encoders (A, B pins);
    ``Wiring()`` is a Pi with nothing on its motor pins (servos only)."""

    left: HBridge | None = None
    right: HBridge | None = None
    left_encoder: tuple[int, int] | None = None
    right_encoder: tuple[int, int] | None = None

    def encoders(self) -> list[tuple[int, tuple[int, int]]]:
        """(side index, (A, B)) for each wired encoder."""
        pairs = [(0, self.left_encoder), (1, self.right_encoder)]
        return [(side, pins) for side, pins in pairs if pins is not None]


def pigpio_driver_wiring(options: Mapping[str, Any]) -> Wiring:
    """The hardware a complete ``[driver.pigpio]`` section describes: EN = PWM, IN1/IN2.
    (How each motor and encoder is mounted is the MotorPair's wiring: sim/wiring.py.)"""
    def bridge(side: str) -> HBridge:
        return HBridge(options[f"{side}_in1"], options[f"{side}_in2"], options[f"{side}_pwm"])

    return Wiring(bridge("left"), bridge("right"), *_encoders(options))


def l298n_driver_wiring(options: Mapping[str, Any]) -> Wiring:
    """The hardware a complete ``[driver.l298n]`` section describes: IN1/IN2 PWM, EN if wired.
    (How each motor and encoder is mounted is the MotorPair's wiring: sim/wiring.py.)"""
    def bridge(side: str) -> HBridge:
        enable = options[f"{side}_enable"]
        return HBridge(options[f"{side}_forward"], options[f"{side}_backward"],
                       enable if enable >= 0 else None)

    return Wiring(bridge("left"), bridge("right"), *_encoders(options))


def _encoders(options: Mapping[str, Any]) -> tuple[tuple[int, int] | None, tuple[int, int] | None]:
    if not options.get("encoders"):
        return None, None
    return ((options["left_encoder_a"], options["left_encoder_b"]),
            (options["right_encoder_a"], options["right_encoder_b"]))


@dataclass
class PinState:
    """Everything pigpiod tracks for one GPIO."""

    mode: int = MODE_INPUT
    pud: int = PUD_OFF
    pwm_duty: int = 0
    pwm_range: int = 255
    pwm_frequency: int = 800
    pwm_active: bool = False
    hw_frequency: int = 0
    hw_duty: int = 0
    servo_us: int = 0
    glitch_us: int = 0
    watchdog_ms: int = 0


@dataclass
class NotifySink:
    """A notification handle: its socket connection, bit mask and sequence number."""

    conn: Connection
    mask: int = 0
    seqno: int = 0


class GpioBank:
    """The state of the Pi's GPIO as pigpiod sees it, and the command interpreter.

    ``execute`` is pure state manipulation; the server owns the sockets. ``on_output`` is
    called (under the bank lock) after every change that can affect an output level.
    """

    def __init__(self, on_output: Callable[[], None] | None = None) -> None:
        self.lock = threading.RLock()
        self.pins = [PinState() for _ in range(54)]
        self.levels = 0  # bank 1 (GPIO 0-31) level word
        self.notify: dict[int, NotifySink] = {}
        self.log: list[tuple[int, int, int]] = []
        self.log_limit = 10000
        self.start_mono = time.monotonic()
        self.on_output = on_output or (lambda: None)
        self.on_command: Callable[[Request, float], None] | None = None
        self.handlers = self._handlers()
        self.scripts = ScriptHost(self._script_gpio, self.lock)

    # -- helpers used by the motor mapping and the encoder generator -------------------------

    def tick(self) -> int:
        return int((time.monotonic() - self.start_mono) * 1e6) & 0xFFFFFFFF

    def output_level(self, gpio: int) -> float:
        """The average level (0..1) a pin drives: PWM duty fraction, or its digital level."""
        with self.lock:
            pin = self.pins[gpio]
            if pin.hw_frequency and gpio in HARDWARE_PWM_CHANNEL:
                return pin.hw_duty / HARDWARE_DUTY_FULL
            if pin.pwm_active:
                return pin.pwm_duty / pin.pwm_range
            if pin.mode != MODE_OUTPUT:
                return 0.0
            return float((self.levels >> gpio) & 1) if gpio < 32 else 0.0

    def stop_pwm(self) -> None:
        """What pigpiod's exit does to its outputs: DMA and hardware PWM stop."""
        with self.lock:
            for pin in self.pins:
                pin.pwm_active, pin.pwm_duty, pin.hw_frequency, pin.hw_duty = False, 0, 0, 0
            self.notify.clear()
            self.on_output()

    def set_input_level(self, gpio: int, level: int) -> None:
        """Drive an input from outside (no report: used before any client listens)."""
        with self.lock:
            self.levels = (self.levels | (1 << gpio)) if level else (self.levels & ~(1 << gpio))

    # -- the interpreter ----------------------------------------------------------------------

    def execute(self, req: Request, ext: bytes, conn: Connection) -> int:
        """Run one command; return its result (negative = pigpio error code)."""
        with self.lock:
            if len(self.log) < self.log_limit:
                self.log.append((req.cmd, req.p1, req.p2))
            handler = self.handlers.get(req.cmd)
            result = PI_UNKNOWN_COMMAND if handler is None else handler(req, ext, conn)
        if self.on_command is not None:
            self.on_command(req, time.monotonic())
        return result

    def _handlers(self) -> dict[int, Callable[[Request, bytes, Connection], int]]:
        return {
            CMD_MODES: self._modes, CMD_MODEG: self._modeg, CMD_PUD: self._pud,
            CMD_READ: self._read, CMD_WRITE: self._write, CMD_PWM: self._pwm,
            CMD_PRS: self._prs, CMD_PFS: self._pfs, CMD_SERVO: self._servo,
            CMD_WDOG: self._wdog, CMD_BR1: lambda r, e, c: self.levels,
            CMD_BR2: lambda r, e, c: 0, CMD_TICK: lambda r, e, c: self.tick(),
            CMD_HWVER: lambda r, e, c: PI4B_REVISION, CMD_PIGPV: lambda r, e, c: PIGPIO_VERSION,
            CMD_NB: self._nb, CMD_NC: self._nc, CMD_NOIB: self._noib,
            CMD_PRG: self._prg, CMD_PFG: self._pfg, CMD_PRRG: self._prrg,
            CMD_GDC: self._gdc, CMD_GPW: self._gpw, CMD_HP: self._hp,
            CMD_FG: self._fg, CMD_FN: self._fn,
            CMD_PROC: lambda r, e, c: self.scripts.store(e),
            CMD_PROCR: lambda r, e, c: self.scripts.run(r.p1, e),
            CMD_PROCU: lambda r, e, c: self.scripts.update(r.p1, e),
            CMD_PROCS: lambda r, e, c: self.scripts.stop(r.p1),
            CMD_PROCD: lambda r, e, c: self.scripts.delete(r.p1),
            CMD_PROCP: self._procp,
        }

    def _procp(self, req: Request, ext: bytes, conn: Connection) -> int:
        count, data = self.scripts.status(req.p1)
        conn.reply_ext = data
        return count

    def _script_gpio(self, name: str, values: list[int]) -> int:
        """A GPIO command given by a running script (under the bank lock)."""
        cmd = {"w": CMD_WRITE, "pwm": CMD_PWM, "hp": CMD_HP}[name]
        ext = struct.pack("<I", values[2] & 0xFFFFFFFF) if name == "hp" else b""
        req = Request(cmd, values[0] & 0xFFFFFFFF, values[1] & 0xFFFFFFFF, len(ext))
        return self.handlers[cmd](req, ext, cast("Connection", None))  # they use no socket

    def _gpio(self, gpio: int, user: bool = False) -> int | None:
        limit = 31 if user else 53
        if 0 <= gpio <= limit:
            return None
        return PI_BAD_USER_GPIO if user else PI_BAD_GPIO

    def _modes(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1)) is not None:
            return err
        if req.p2 > 7:
            return PI_BAD_MODE
        pin = self.pins[req.p1]
        if req.p2 != MODE_OUTPUT:
            pin.pwm_active, pin.hw_frequency = False, 0
        pin.mode = req.p2
        self.on_output()
        return 0

    def _modeg(self, req: Request, ext: bytes, conn: Connection) -> int:
        return self._gpio(req.p1) or self.pins[req.p1].mode

    def _pud(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1)) is not None:
            return err
        if req.p2 > PUD_UP:
            return PI_BAD_PUD
        self.pins[req.p1].pud = req.p2
        return 0

    def _read(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1)) is not None:
            return err
        return (self.levels >> req.p1) & 1 if req.p1 < 32 else 0

    def _write(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1)) is not None:
            return err
        if req.p2 > 1:
            return PI_BAD_LEVEL
        pin = self.pins[req.p1]
        pin.mode, pin.pwm_active, pin.hw_frequency, pin.servo_us = MODE_OUTPUT, False, 0, 0
        if req.p1 < 32:
            bit = 1 << req.p1
            self.levels = (self.levels | bit) if req.p2 else (self.levels & ~bit)
        self.on_output()
        return 0

    def _pwm(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1, user=True)) is not None:
            return err
        pin = self.pins[req.p1]
        if req.p2 > pin.pwm_range:
            return PI_BAD_DUTYCYCLE
        pin.mode, pin.pwm_active, pin.pwm_duty, pin.hw_frequency = MODE_OUTPUT, True, req.p2, 0
        self.on_output()
        return 0

    def _prs(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1, user=True)) is not None:
            return err
        if not 25 <= req.p2 <= 40000:
            return PI_BAD_DUTYRANGE
        pin = self.pins[req.p1]
        pin.pwm_duty = round(pin.pwm_duty * req.p2 / pin.pwm_range)  # the duty fraction stays
        pin.pwm_range = req.p2
        self.on_output()
        return self._real_range(pin)

    def _pfs(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1, user=True)) is not None:
            return err
        self.pins[req.p1].pwm_frequency = nearest_pwm_frequency(req.p2)
        return self.pins[req.p1].pwm_frequency

    def _servo(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1, user=True)) is not None:
            return err
        if req.p2 != 0 and not 500 <= req.p2 <= 2500:
            return PI_BAD_PULSEWIDTH
        pin = self.pins[req.p1]
        pin.servo_us, pin.mode, pin.pwm_active = req.p2, MODE_OUTPUT, False
        self.on_output()
        return 0

    def _wdog(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1, user=True)) is not None:
            return err
        if req.p2 > 60000:
            return PI_BAD_WDOG_TIMEOUT
        self.pins[req.p1].watchdog_ms = req.p2
        return 0

    def _noib(self, req: Request, ext: bytes, conn: Connection) -> int:
        free = [h for h in range(MAX_NOTIFY_HANDLES) if h not in self.notify]
        if not free:
            return PI_NO_HANDLE
        self.notify[free[0]] = NotifySink(conn)
        conn.notify_handle = free[0]
        return free[0]

    def _nb(self, req: Request, ext: bytes, conn: Connection) -> int:
        sink = self.notify.get(req.p1)
        if sink is None:
            return PI_BAD_HANDLE
        sink.mask = req.p2
        return 0

    def _nc(self, req: Request, ext: bytes, conn: Connection) -> int:
        if self.notify.pop(req.p1, None) is None:
            return PI_BAD_HANDLE
        return 0

    def _prg(self, req: Request, ext: bytes, conn: Connection) -> int:
        return self._gpio(req.p1, user=True) or self.pins[req.p1].pwm_range

    def _pfg(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1, user=True)) is not None:
            return err
        pin = self.pins[req.p1]
        return pin.hw_frequency or pin.pwm_frequency

    def _prrg(self, req: Request, ext: bytes, conn: Connection) -> int:
        return self._gpio(req.p1, user=True) or self._real_range(self.pins[req.p1])

    def _gdc(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1, user=True)) is not None:
            return err
        pin = self.pins[req.p1]
        return pin.hw_duty if pin.hw_frequency else pin.pwm_duty

    def _gpw(self, req: Request, ext: bytes, conn: Connection) -> int:
        return self._gpio(req.p1, user=True) or self.pins[req.p1].servo_us

    def _hp(self, req: Request, ext: bytes, conn: Connection) -> int:
        if req.p1 not in HARDWARE_PWM_CHANNEL:
            return PI_NOT_HPWM_GPIO
        if len(ext) != 4:
            return PI_BAD_HPWM_DUTY
        (duty,) = struct.unpack("<I", ext)
        if req.p2 > 187_500_000:
            return PI_BAD_HPWM_FREQ
        if duty > HARDWARE_DUTY_FULL:
            return PI_BAD_HPWM_DUTY
        channel = HARDWARE_PWM_CHANNEL[req.p1]
        for gpio, other in HARDWARE_PWM_CHANNEL.items():  # a channel's pins share its settings
            if other == channel and self.pins[gpio].hw_frequency and gpio != req.p1:
                self.pins[gpio].hw_frequency, self.pins[gpio].hw_duty = req.p2, duty
        pin = self.pins[req.p1]
        pin.mode, pin.pwm_active = (4 if req.p2 else MODE_OUTPUT), False
        pin.hw_frequency, pin.hw_duty = req.p2, duty if req.p2 else 0
        self.on_output()
        return 0

    def _fg(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1, user=True)) is not None:
            return err
        if req.p2 > 300_000:
            return PI_BAD_FILTER
        self.pins[req.p1].glitch_us = req.p2
        return 0

    def _fn(self, req: Request, ext: bytes, conn: Connection) -> int:
        if (err := self._gpio(req.p1, user=True)) is not None:
            return err
        return PI_BAD_FILTER if req.p2 > 300_000 else 0

    @staticmethod
    def _real_range(pin: PinState) -> int:
        return 200_000 // pin.pwm_frequency


# -- the TCP server --------------------------------------------------------------------------------


class Connection:
    """One client socket: a command stream, or a notification stream after NOIB."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.send_lock = threading.Lock()
        self.notify_handle: int | None = None
        self.closed = False
        #: bytes a command's answer carries after the reply header (PROCP)
        self.reply_ext = b""

    def send(self, data: bytes) -> bool:
        with self.send_lock:
            if self.closed:
                return False
            try:
                self.sock.sendall(data)
            except OSError:
                self.closed = True
                return False
        return True

    def recv_exact(self, size: int) -> bytes | None:
        chunks, need = [], size
        while need:
            try:
                chunk = self.sock.recv(need)
            except OSError:
                return None
            if not chunk:
                return None
            chunks.append(chunk)
            need -= len(chunk)
        return b"".join(chunks)

    def close(self) -> None:
        with self.send_lock:
            self.closed = True
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()


def default_motors(counts_per_rev: int = 240, max_speed_rad_s: float = 20.0) -> MotorPair:
    """A real-time MotorPair with a modest encoder resolution (sane notification rates)."""
    return MotorPair(WheelMotor(max_speed_rad_s=max_speed_rad_s, counts_per_rev=counts_per_rev),
                     WheelMotor(max_speed_rad_s=max_speed_rad_s, counts_per_rev=counts_per_rev))


class PigpiodEmulator:
    """pigpiod on a TCP port, with L298N bridges and quadrature encoders on its pins.

    ``start()`` listens (port 0 = ephemeral; the bound port is kept for restarts), ``stop()``
    is pigpiod exiting (every socket drops, PWM stops), ``start()`` again is the restart.
    Writes to the bridge pins set the MotorPair duties; encoder edges generated from the
    MotorPair counts go to every notification handle whose mask covers them.
    """

    def __init__(self, wiring: Wiring, motors: MotorPair | None = None, *,
                 host: str = "127.0.0.1", port: int = 0, edge_poll_s: float = 0.002) -> None:
        self.wiring = wiring
        self.motors = motors or default_motors()
        self.host, self.port = host, port
        self.edge_poll_s = edge_poll_s
        self.bank = GpioBank(on_output=self._apply_outputs)
        self.running = False
        self.unresponsive = False  # fault switch: a hung pigpiod reads commands, never replies
        self.connections_accepted = 0
        self._listener: socket.socket | None = None
        self._conns: set[Connection] = set()
        self._accepter: threading.Thread | None = None
        self._encoders: threading.Thread | None = None
        self._lock = threading.Lock()
        self._counts = [0, 0]
        self._halt = threading.Event()
        self._init_encoder_levels()

    # -- lifecycle ----------------------------------------------------------------------------

    def start(self) -> PigpiodEmulator:
        """Listen (again). Returns self: ``emu = PigpiodEmulator(...).start()``."""
        with self._lock:
            if self.running:
                return self
            listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            listener.bind((self.host, self.port))
            listener.listen(16)
            self.port = listener.getsockname()[1]
            self._listener, self.running = listener, True
            self._accepter = self._spawn(self._accept_loop, "pigpiod-accept")
            if self._encoders is None and self.wiring.encoders():
                self._halt.clear()
                self._encoders = self._spawn(self._edge_loop, "pigpiod-edges")
        return self

    def stop(self) -> None:
        """pigpiod exits: stop listening, drop every client, stop PWM (the motors coast).

        The wheels and their encoders keep turning; edges while pigpiod is down are lost.
        """
        with self._lock:
            if not self.running:
                return
            self.running = False
            listener, self._listener = self._listener, None
            conns, self._conns = list(self._conns), set()
        if listener is not None:
            with contextlib.suppress(OSError):
                listener.shutdown(socket.SHUT_RDWR)  # wakes the thread blocked in accept()
            listener.close()
        for conn in conns:
            conn.close()
        if self._accepter is not None:
            self._accepter.join(timeout=2.0)
            self._accepter = None
        self.bank.scripts.stop_all()  # pigpiod's scripts end with it
        self.bank.stop_pwm()

    def close(self) -> None:
        """Stop pigpiod and the emulated hardware (the encoder thread)."""
        self.stop()
        self._halt.set()
        if self._encoders is not None:
            self._encoders.join(timeout=2.0)
            self._encoders = None

    def __enter__(self) -> PigpiodEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def servo_pulse_us(self, gpio: int) -> float:
        """The servo pulse width a GPIO carries now, µs (0 = off)."""
        return float(self.bank.pins[gpio].servo_us)

    @property
    def address(self) -> tuple[str, int]:
        return self.host, self.port

    def observed_duties(self) -> tuple[float, float]:
        """Signed duty (-1..1) of each bridge as the pins drive it now."""
        with self.bank.lock:
            left, right = (0.0 if bridge is None else bridge.duty(self.bank.output_level)
                           for bridge in (self.wiring.left, self.wiring.right))
            return left, right

    def emitted_counts(self) -> tuple[int, int]:
        """Encoder edge counts the pins have shown so far (what a perfect listener counted)."""
        with self.bank.lock:
            return self._counts[0], self._counts[1]

    def command_log(self) -> list[tuple[int, int, int]]:
        with self.bank.lock:
            return list(self.bank.log)

    # -- internals ----------------------------------------------------------------------------

    def _spawn(self, target: Callable[[], None], name: str) -> threading.Thread:
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        return thread

    def _apply_outputs(self) -> None:
        left, right = self.observed_duties()
        self.motors.set_duties(left, right)

    def _accept_loop(self) -> None:
        listener = self._listener
        while self.running and listener is not None:
            try:
                sock, _ = listener.accept()
            except OSError:
                return
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn = Connection(sock)
            with self._lock:
                if not self.running:
                    conn.close()
                    return
                self._conns.add(conn)
                self.connections_accepted += 1
            threading.Thread(target=self._serve, args=(conn,), name="pigpiod-conn",
                             daemon=True).start()

    def _serve(self, conn: Connection) -> None:
        try:
            while True:
                header = conn.recv_exact(REQUEST.size)
                if header is None:
                    return
                req = decode_request(header)
                ext = conn.recv_exact(req.p3) if req.p3 else b""
                if ext is None:
                    return
                if self.unresponsive:
                    continue
                result = self.bank.execute(req, ext, conn)
                reply, conn.reply_ext = encode_reply(req, result) + conn.reply_ext, b""
                if not conn.send(reply):
                    return
        finally:
            self._forget(conn)

    def _forget(self, conn: Connection) -> None:
        with self._lock:
            self._conns.discard(conn)
        with self.bank.lock:
            handle = conn.notify_handle
            if handle is not None and self.bank.notify.get(handle, None) is not None \
                    and self.bank.notify[handle].conn is conn:
                del self.bank.notify[handle]
        conn.close()

    # -- encoders -----------------------------------------------------------------------------

    def _init_encoder_levels(self) -> None:
        counts = self.motors.counts()
        for side, (pin_a, pin_b) in self.wiring.encoders():
            self._counts[side] = counts[side]
            a, b = quadrature_levels(counts[side])
            self.bank.set_input_level(pin_a, a)
            self.bank.set_input_level(pin_b, b)

    def _edge_loop(self) -> None:
        idle_poll = max(self.edge_poll_s, 0.02)
        while not self._halt.is_set():
            moving = self._emit_edges()
            self._halt.wait(self.edge_poll_s if moving else idle_poll)

    def _emit_edges(self) -> bool:
        counts = self.motors.counts()
        speeds = self.motors.speeds()
        targets = self.motors.targets()
        moving = any(abs(v) > 1e-3 for v in (*speeds, *targets))
        with self.bank.lock:
            before = self.bank.levels
            words = self._step_levels(counts)
            if words:
                self._send_reports(before, words)
        return moving

    def _step_levels(self, counts: tuple[int, int]) -> list[int]:
        """Walk each encoder one edge at a time to its new count; the level word after each."""
        words: list[int] = []
        for side, (pin_a, pin_b) in self.wiring.encoders():
            target = counts[side]
            while self._counts[side] != target:
                self._counts[side] += 1 if target > self._counts[side] else -1
                a, b = quadrature_levels(self._counts[side])
                word = self.bank.levels
                word = (word | (1 << pin_a)) if a else (word & ~(1 << pin_a))
                word = (word | (1 << pin_b)) if b else (word & ~(1 << pin_b))
                self.bank.levels = word
                words.append(word)
        return words

    def _send_reports(self, before: int, words: Iterable[int]) -> None:
        tick = self.bank.tick()
        previous = before
        batches: dict[int, list[bytes]] = {}
        for word in words:
            changed, previous = word ^ previous, word
            for handle, sink in self.bank.notify.items():
                if sink.mask & changed:
                    batches.setdefault(handle, []).append(encode_report(sink.seqno, 0, tick, word))
                    sink.seqno = (sink.seqno + 1) & 0xFFFF
        for handle, records in batches.items():
            self.bank.notify[handle].conn.send(b"".join(records))


# -- standalone ------------------------------------------------------------------------------------


def _pins(text: str, count: tuple[int, ...]) -> tuple[int, ...]:
    values = tuple(int(part) for part in text.split(","))
    if len(values) not in count:
        raise argparse.ArgumentTypeError(f"expected {' or '.join(map(str, count))} pins: {text!r}")
    if any(not 0 <= v <= 31 for v in values):
        raise argparse.ArgumentTypeError(f"GPIO numbers must be 0-31: {text!r}")
    return values


def _bridge(text: str, reversed_: bool) -> HBridge:
    pins = _pins(text, (2, 3))
    return HBridge(pins[0], pins[1], pins[2] if len(pins) == 3 else None, reversed_)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m sim.pigpiod_emulator",
                                     description="Emulated pigpiod with two L298N-driven wheels.")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8888, help="0 = any free port")
    parser.add_argument("--left", default="23,24,12", metavar="IN1,IN2[,EN]",
                        help="left bridge pins (default: the pigpio driver's defaults)")
    parser.add_argument("--right", default="27,22,13", metavar="IN1,IN2[,EN]")
    parser.add_argument("--left-encoder", default="5,6", metavar="A,B", help="'' = none")
    parser.add_argument("--right-encoder", default="20,21", metavar="A,B", help="'' = none")
    parser.add_argument("--reverse-left", action="store_true", help="left motor wired reversed")
    parser.add_argument("--reverse-right", action="store_true")
    parser.add_argument("--counts-per-rev", type=int, default=240,
                        help="encoder edges (4 per quadrature cycle) per wheel revolution")
    parser.add_argument("--max-speed", type=float, default=20.0,
                        help="wheel speed at full duty, rad/s")
    return parser.parse_args(argv)


def wiring_from_args(args: argparse.Namespace) -> Wiring:
    def encoder(text: str) -> tuple[int, int] | None:
        if not text:
            return None
        a, b = _pins(text, (2,))
        return a, b

    return Wiring(_bridge(args.left, args.reverse_left), _bridge(args.right, args.reverse_right),
                  encoder(args.left_encoder), encoder(args.right_encoder))


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    emulator = PigpiodEmulator(wiring_from_args(args),
                               default_motors(args.counts_per_rev, args.max_speed),
                               host=args.host, port=args.port).start()
    print(f"pigpiod emulator listening on {emulator.host}:{emulator.port} "
          f"(PIGPIO_ADDR={emulator.host} PIGPIO_PORT={emulator.port}); "
          "SIGUSR1 = pigpiod stops, SIGUSR2 = pigpiod restarts", flush=True)
    done = threading.Event()
    signal.signal(signal.SIGUSR1, lambda *_: threading.Thread(target=emulator.stop).start())
    signal.signal(signal.SIGUSR2, lambda *_: threading.Thread(target=emulator.start).start())
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    done.wait()
    emulator.close()


if __name__ == "__main__":
    main()
