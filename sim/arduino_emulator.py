# Emulated Arduino running ROSArduinoBridge firmware, on a pseudo-terminal with a stable symlink.
from __future__ import annotations

import argparse
import contextlib
import os
import random
import select
import signal
import sys
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from drivers.rosarduino import (
    ANALOG_READ,
    ANALOG_WRITE,
    AUTO_STOP_S,
    BAUDRATE,
    DEFAULT_GAINS,
    DIGITAL_READ,
    DIGITAL_WRITE,
    GET_BAUDRATE,
    INVALID_COMMAND,
    MAX_PWM,
    MOTOR_RAW_PWM,
    MOTOR_SPEEDS,
    OK,
    PID_RATE_HZ,
    PIN_MODE,
    PING,
    READ_ENCODERS,
    RESET_ENCODERS,
    UPDATE_PID,
    encode_reply,
    format_counts,
    ticks_to_rad_s,
    wrap_long,
)
from sim.motor_model import MotorPair

ARG_BUFFER = 15  # the firmware's argv buffers are char[16]
OK_REPLY_COMMANDS = PIN_MODE + DIGITAL_WRITE + ANALOG_WRITE  # answer OK
ZERO_REPLY_COMMANDS = ANALOG_READ + DIGITAL_READ + PING  # answer 0 (nothing attached)


@dataclass(frozen=True)
class ReceivedCommand:
    """One CR-terminated command the firmware ran, with the monotonic time it was parsed."""

    t_mono: float
    text: str


class Firmware:
    """The ROSArduinoBridge command loop as a pure byte-in, byte-out machine (no I/O).

    Parsing follows the firmware character by character: CR ends a command, spaces step
    through at most two arguments, the command is the last character of the first word, and
    arguments are read with ``atoi``. The PID itself is modelled as ideal: ``m L R`` sets the
    wheel set-points to ``ticks * pid_rate`` counts per second and the :class:`MotorPair`'s
    first-order lag does the rest. ``o L R`` drives the motors with duty ``L/255``.
    """

    def __init__(self, motors: MotorPair, *, pid_rate: float = PID_RATE_HZ,
                 auto_stop_s: float = AUTO_STOP_S, clock: Callable[[], float] = time.monotonic,
                 seed: int = 1) -> None:
        self.motors = motors
        self.pid_rate = pid_rate
        self.auto_stop_s = auto_stop_s
        self.clock = clock
        self.garbage = False
        self.mute = False
        self.history: deque[ReceivedCommand] = deque(maxlen=4096)
        self.resets = 0
        self.auto_stops = 0
        self._rng = random.Random(seed)
        self.reset()

    def reset(self) -> None:
        """Power-on or DTR reset: motors off, encoders zero, gains back to defaults."""
        self.motors.set_targets(0.0, 0.0)
        self._offsets = self._raw_counts()
        self.gains = DEFAULT_GAINS
        self.mode = "stopped"  # stopped | pid | pwm
        self.ticks_per_frame = (0, 0)
        self.pwm = (0, 0)
        self.last_motor_command = self.clock()
        self._clear_parser()
        self.resets += 1

    def feed(self, data: bytes) -> bytes:
        """Consume bytes from the host; return the bytes the board answers."""
        if self.mute:
            return b""
        out = bytearray()
        for byte in data:
            reply = self._feed_char(chr(byte))
            if reply is not None:
                out += self._garble(reply) if self.garbage else encode_reply(reply)
        return bytes(out)

    def tick(self) -> None:
        """The part of ``loop()`` after serial input: the auto-stop check."""
        idle = self.clock() - self.last_motor_command
        if idle > self.auto_stop_s and self.mode != "stopped":
            self.motors.set_targets(0.0, 0.0)
            self.mode = "stopped"
            self.auto_stops += 1

    def encoder_counts(self) -> tuple[int, int]:
        left, right = self._raw_counts()
        return wrap_long(left - self._offsets[0]), wrap_long(right - self._offsets[1])

    def _raw_counts(self) -> tuple[int, int]:
        return self.motors.counts()

    # -- parser ------------------------------------------------------------------------------

    def _clear_parser(self) -> None:
        self._cmd = ""
        self._args = ["", ""]
        self._arg = 0

    def _feed_char(self, char: str) -> str | None:
        if char == "\r":
            reply = self._run(self._cmd, self._args[0], self._args[1])
            self._clear_parser()
            return reply
        if char == " ":
            self._arg = min(self._arg + 1, 2)
        elif self._arg == 0:
            self._cmd = char
        elif len(self._args[self._arg - 1]) < ARG_BUFFER:
            self._args[self._arg - 1] += char
        return None

    def _run(self, cmd: str, argv1: str, argv2: str) -> str:
        text = " ".join(filter(None, (cmd, argv1, argv2)))
        self.history.append(ReceivedCommand(self.clock(), text))
        arg1, arg2 = _atoi(argv1), _atoi(argv2)
        handlers: dict[str, Callable[[], str]] = {
            GET_BAUDRATE: lambda: str(BAUDRATE),
            READ_ENCODERS: self._read_encoders,
            RESET_ENCODERS: self._reset_encoders,
            MOTOR_SPEEDS: lambda: self._motor_speeds(arg1, arg2),
            MOTOR_RAW_PWM: lambda: self._raw_pwm(arg1, arg2),
            UPDATE_PID: lambda: self._update_pid(argv1),
        }
        if cmd in handlers:
            return handlers[cmd]()
        if cmd and cmd in OK_REPLY_COMMANDS:
            return OK
        if cmd and cmd in ZERO_REPLY_COMMANDS:
            return "0"
        return INVALID_COMMAND

    # -- commands ----------------------------------------------------------------------------

    def _read_encoders(self) -> str:
        return format_counts(*self.encoder_counts())

    def _reset_encoders(self) -> str:
        self._offsets = self._raw_counts()
        if self.mode == "pid":  # resetPID() zeroes the target; raw PWM is left alone
            self.ticks_per_frame = (0, 0)
            self.motors.set_targets(0.0, 0.0)
        return OK

    def _motor_speeds(self, left_ticks: int, right_ticks: int) -> str:
        self.last_motor_command = self.clock()
        self.ticks_per_frame = (left_ticks, right_ticks)
        self.mode = "stopped" if left_ticks == 0 and right_ticks == 0 else "pid"
        self.motors.set_targets(self.ticks_to_rad_s(left_ticks, self.motors.left.counts_per_rev),
                                self.ticks_to_rad_s(right_ticks, self.motors.right.counts_per_rev))
        return OK

    def _raw_pwm(self, left: int, right: int) -> str:
        self.last_motor_command = self.clock()
        self.pwm = (_clamp_pwm(left), _clamp_pwm(right))
        self.mode = "pwm"
        self.motors.set_duties(self.pwm[0] / MAX_PWM, self.pwm[1] / MAX_PWM)
        return OK

    def _update_pid(self, argv1: str) -> str:
        values = [_atoi(part) for part in argv1.split(":") if part][:4]
        values += [0] * (4 - len(values))
        self.gains = (values[0], values[1], values[2], values[3])
        return OK

    def ticks_to_rad_s(self, ticks_per_frame: int, counts_per_rev: int) -> float:
        return ticks_to_rad_s(ticks_per_frame, counts_per_rev, self.pid_rate)

    def _garble(self, reply: str) -> bytes:
        """What a host sees from a board with a baud mismatch or a noisy cable."""
        noise = bytes(self._rng.randrange(0x80, 0x100) for _ in range(self._rng.randint(2, 9)))
        return noise + encode_reply(reply[::-1])


def _atoi(text: str) -> int:
    """C ``atoi``: optional sign and leading digits, 0 when there are none."""
    text = text.lstrip(" \t")
    sign, digits = 1, ""
    if text[:1] in "+-" and text:
        sign, text = (-1 if text[0] == "-" else 1), text[1:]
    for char in text:
        if not char.isdigit():
            break
        digits += char
    return sign * int(digits) if digits else 0


def _clamp_pwm(value: int) -> int:
    return max(-MAX_PWM, min(MAX_PWM, value))


class ArduinoEmulator:
    """A :class:`Firmware` behind a pseudo-terminal, reachable at a stable symlink ``link``.

    A thread serves the pty. Opening the port resets the board (as DTR does on an Uno/Nano):
    encoders go to zero, motors stop, and input is ignored for ``boot_s`` while the bootloader
    runs. :meth:`unplug` closes the pty and removes the link while the board keeps running on
    its own (auto-stop still applies); :meth:`replug` makes a new pty behind the same link.
    ``garbage`` and ``mute`` switch the firmware into answering garbage or nothing.
    """

    def __init__(self, link: str | Path, motors: MotorPair | None = None, *,
                 pid_rate: float = PID_RATE_HZ, auto_stop_s: float = AUTO_STOP_S,
                 boot_s: float = 0.0, reset_on_open: bool = True, seed: int = 1) -> None:
        self.link = Path(link)
        self.motors = motors or MotorPair()
        self.firmware = Firmware(self.motors, pid_rate=pid_rate, auto_stop_s=auto_stop_s,
                                 seed=seed)
        self.boot_s = boot_s
        self.reset_on_open = reset_on_open
        self.opens = 0
        self.bytes_dropped = 0
        self._lock = threading.Lock()
        self._master: int | None = None
        self._pty_name = ""
        self._host_present = False
        self._boot_until = 0.0
        self._running = threading.Event()
        self._thread: threading.Thread | None = None

    # -- switches ----------------------------------------------------------------------------

    @property
    def garbage(self) -> bool:
        return self.firmware.garbage

    @garbage.setter
    def garbage(self, on: bool) -> None:
        self.firmware.garbage = on

    @property
    def mute(self) -> bool:
        return self.firmware.mute

    @mute.setter
    def mute(self, on: bool) -> None:
        self.firmware.mute = on

    @property
    def plugged(self) -> bool:
        return self._master is not None

    @property
    def pty_name(self) -> str:
        return self._pty_name

    # -- lifecycle ---------------------------------------------------------------------------

    def start(self) -> ArduinoEmulator:
        self.replug()
        self._running.set()
        self._thread = threading.Thread(target=self._serve, name="arduino-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._running.clear()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        self.unplug()

    def __enter__(self) -> ArduinoEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def unplug(self) -> None:
        """The USB cable is pulled: the port and its link vanish; the board keeps running."""
        with self._lock:
            master, self._master = self._master, None
            self._host_present = False
        if master is not None:
            os.close(master)
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()

    def replug(self) -> None:
        """The cable is plugged in again: a new pty behind the same link."""
        if self.plugged:
            return
        master, slave = os.openpty()
        tty.setraw(master)
        name = os.ttyname(slave)
        os.close(slave)  # hold no slave fd, so a host opening the port shows up as POLLHUP ending
        temporary = self.link.with_name(self.link.name + ".new")
        with contextlib.suppress(FileNotFoundError):
            temporary.unlink()
        temporary.symlink_to(name)
        temporary.replace(self.link)
        with self._lock:
            self._master, self._pty_name, self._host_present = master, name, False

    # -- the board's main loop ---------------------------------------------------------------

    def _serve(self) -> None:
        while self._running.is_set():
            with self._lock:  # unplug() waits for this poll, so the fd is never closed under us
                served = self._master is not None and self._serve_once(self._master)
            if not served:
                time.sleep(0.005)
            self.firmware.tick()

    def _serve_once(self, master: int) -> bool:
        """Handle one poll of the pty; False when no host has the port open."""
        poller = select.poll()
        poller.register(master, select.POLLIN)
        try:
            events = poller.poll(10)
        except (OSError, ValueError):
            return False
        flags = events[0][1] if events else 0
        if flags & select.POLLHUP and not flags & select.POLLIN:
            self._host_present = False
            return False
        if not self._host_present:
            self._host_opened()
        if flags & select.POLLIN:
            return self._read_and_answer(master)
        return True

    def _host_opened(self) -> None:
        self._host_present = True
        self.opens += 1
        if self.reset_on_open:
            self.firmware.reset()
            self._boot_until = time.monotonic() + self.boot_s

    def _read_and_answer(self, master: int) -> bool:
        try:
            data = os.read(master, 4096)
        except OSError:
            self._host_present = False
            return False
        if time.monotonic() < self._boot_until:
            self.bytes_dropped += len(data)
            return True
        reply = self.firmware.feed(data)
        if reply:
            with contextlib.suppress(OSError):
                os.write(master, reply)
        return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m sim.arduino_emulator",
        description="Emulated Arduino running ROSArduinoBridge on a pseudo-terminal. "
                    "SIGUSR1 toggles garbage replies, SIGUSR2 unplugs/replugs the port.")
    parser.add_argument("--link", default="./arduino", help="symlink to create for the port")
    parser.add_argument("--pid-rate", type=float, default=PID_RATE_HZ, help="PID frames per second")
    parser.add_argument("--boot", type=float, default=2.0, help="bootloader seconds after open")
    parser.add_argument("--auto-stop", type=float, default=AUTO_STOP_S, help="auto-stop seconds")
    parser.add_argument("--counts-per-rev", type=int, default=1440, help="encoder counts per rev")
    args = parser.parse_args(argv)
    motors = MotorPair()
    motors.left.counts_per_rev = motors.right.counts_per_rev = args.counts_per_rev
    emulator = ArduinoEmulator(args.link, motors, pid_rate=args.pid_rate,
                               auto_stop_s=args.auto_stop, boot_s=args.boot)
    _install_switches(emulator)
    with emulator:
        print(f"ROSArduinoBridge emulator: connect to {Path(args.link).absolute()} "
              f"(-> {emulator.pty_name}), {BAUDRATE} baud; pid {args.pid_rate:g} Hz; "
              f"{args.counts_per_rev} counts/rev", flush=True)
        stopped = threading.Event()
        signal.signal(signal.SIGTERM, lambda *_: stopped.set())
        with contextlib.suppress(KeyboardInterrupt):
            while not stopped.wait(0.2):
                pass
    return 0


def _install_switches(emulator: ArduinoEmulator) -> None:
    def toggle_garbage(*_: object) -> None:
        emulator.garbage = not emulator.garbage
        print(f"garbage {'on' if emulator.garbage else 'off'}", flush=True)

    def toggle_plug(*_: object) -> None:
        if emulator.plugged:
            emulator.unplug()
        else:
            emulator.replug()
        print(f"{'plugged' if emulator.plugged else 'unplugged'}", flush=True)

    signal.signal(signal.SIGUSR1, toggle_garbage)
    signal.signal(signal.SIGUSR2, toggle_plug)


if __name__ == "__main__":
    sys.exit(main())
