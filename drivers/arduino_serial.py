# Motor driver for an Arduino running ROSArduinoBridge firmware: CR-terminated lines over serial.
from __future__ import annotations

import asyncio
import contextlib
import math
import os
import select
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from base.options import option
from base.ports import open_error
from drivers.base import (
    DriverFault,
    EncoderReading,
    MotorDriver,
    encoder_inverted,
    inversion_signs,
    motor_inverted,
)
from drivers.host_load import host_busy
from drivers.rosarduino import (
    AUTO_STOP_S,
    BAUDRATE,
    DEFAULT_GAINS,
    MAX_PWM,
    MOTOR_RAW_PWM,
    MOTOR_SPEEDS,
    PID_RATE_HZ,
    READ_ENCODERS,
    UPDATE_PID,
    LineSplitter,
    ProtocolError,
    count_delta,
    decode_line,
    encode_command,
    encode_pid,
    parse_counts,
    parse_ok,
    rad_s_to_pwm,
    rad_s_to_ticks,
)

# -- I/O: one serial port, driven by the event loop --------------------------------------------

class LateReplies:
    """Replies that came after ``timeout_s`` because the host was late, and why it was."""

    def __init__(self) -> None:
        self.extended = 0  # budgets extended because the host was late
        self.late = 0  # replies that came in the extension
        self.slowest_s = 0.0
        self.last_reason: str | None = None

    def waiting(self, reason: str) -> None:
        self.extended += 1
        self.last_reason = reason

    def replied(self, after_s: float, within_s: float) -> None:
        self.slowest_s = max(self.slowest_s, after_s)
        if after_s > within_s:
            self.late += 1

    def health(self) -> dict[str, Any]:
        return {"late_replies": self.late, "slowest_reply_ms": round(self.slowest_s * 1e3, 1),
                "late_host_reason": self.last_reason}


class BridgeLink:
    """Request/reply over an open serial port, without threads: non-blocking fd + add_reader.

    Requests are written at once (never queued behind a slow one) and replies are matched to
    them in order, as the firmware answers one line per command. A timeout, a garbled line or
    an unexpected line poisons the link (``error`` set); a read error or EOF marks it lost.
    Writes happen under a lock that :meth:`send_now` shares, so another thread can put a
    line on the wire between two of the event loop's, never inside one.
    """

    def __init__(self, port: Any, on_fault: Callable[[str], None],
                 late: LateReplies | None = None) -> None:
        self._port = port
        self._fd: int = port.fileno()
        self._loop = asyncio.get_running_loop()
        self._on_fault = on_fault
        self._splitter = LineSplitter()
        self._pending: deque[tuple[str, asyncio.Future[str] | None]] = deque()
        self._out = bytearray()
        self._write_lock = threading.RLock()
        self.error: str | None = None
        self.lost = False
        self.closed = False
        self.last_rx_mono = 0.0
        #: replies that came only in the longer budget of a late host (shared across links)
        self.late = late or LateReplies()
        self._loop.add_reader(self._fd, self._on_readable)

    async def request(self, line: bytes, reply_within_s: float,
                      late_host_s: float = 0.0) -> str:
        """Send one command and return its reply line: within ``reply_within_s``, or, while
        the host is late (:meth:`_host_late`), within ``late_host_s`` in all."""
        command = line.decode("ascii").rstrip("\r")
        if self.error is not None:
            raise DriverFault(self.error)
        future: asyncio.Future[str] = self._loop.create_future()
        sent = time.monotonic()
        with self._write_lock:  # the reply order is the write order, also for send_now()
            self._pending.append((command, future))
            self.send(line)
        budget, waited = max(reply_within_s, late_host_s), 0.0
        while True:
            slice_s = min(reply_within_s, budget - waited)
            deadline = self._loop.time() + slice_s
            try:
                # asyncio.timeout, not wait_for: Python 3.11's wait_for swallows a cancellation
                # that arrives with the reply, and the cancelled poll task would run on forever
                async with asyncio.timeout(slice_s):
                    reply = await asyncio.shield(future)
                break
            except TimeoutError:
                if future.done() and not future.cancelled():
                    # the reply was read in the same loop pass as the expired deadline (the
                    # loop had been blocked): the board answered, the lateness was ours
                    reply = future.result()
                    break
                waited = time.monotonic() - sent
                why = self._host_late(sent, self._loop.time() - deadline, slice_s)
                if why is None or waited >= budget - 1e-3:
                    self._poison(f"no reply to {command!r} within {reply_within_s:g} s"
                                 if why is None else f"no reply to {command!r} within "
                                 f"{waited:.2g} s, the host late ({why})")
                    raise DriverFault(self.error or "timeout") from None
                self.late.waiting(why)
        self.late.replied(time.monotonic() - sent, reply_within_s)
        return reply

    def _host_late(self, sent: float, overdue_s: float, slice_s: float) -> str | None:
        """Why a missing reply may be this host's fault, not the board's: part of a reply
        arrived, the event loop woke late, or the CPUs are busy; None: the board is silent."""
        if self.last_rx_mono > sent:
            return "bytes from the board arrived after the request"
        if overdue_s >= max(0.05, slice_s / 4):
            return f"the event loop woke {overdue_s * 1e3:.0f} ms late"
        return host_busy()

    def send(self, data: bytes) -> None:
        """Write bytes without waiting for a reply (also used on a poisoned link to stop)."""
        if self.lost:
            raise DriverFault(self.error or "serial port lost")
        if not self._out:
            try:
                written = os.write(self._fd, data)
            except BlockingIOError:
                written = 0
            except OSError as exc:
                self._lose(f"serial write failed: {exc}")
                raise DriverFault(self.error or str(exc)) from None
            data = data[written:]
            if not data:
                return
            self._loop.add_writer(self._fd, self._on_writable)
        self._out += data

    def close(self) -> None:
        self._loop.remove_reader(self._fd)
        self._loop.remove_writer(self._fd)
        self._fail_pending(DriverFault("serial link closed"))
        with self._write_lock:  # send_now() must never write to a closed (reused) fd
            self.closed = True
            self._port.close()

    def _on_readable(self) -> None:
        try:
            data = os.read(self._fd, 1024)
        except BlockingIOError:
            return
        except OSError as exc:
            self._lose(f"serial port vanished: {exc}")
            return
        if not data:
            self._lose("serial port vanished (end of file)")
            return
        self.last_rx_mono = time.monotonic()
        try:
            for raw in self._splitter.feed(data):
                self._dispatch(decode_line(raw))
        except ProtocolError as exc:
            self._poison(str(exc))

    def _dispatch(self, line: str) -> None:
        if not self._pending:
            raise ProtocolError(f"unexpected line from the board: {line!r}")
        _, future = self._pending.popleft()
        if future is not None and not future.done():  # None: send_now()'s, nobody waits
            future.set_result(line)

    def _on_writable(self) -> None:
        with self._write_lock:
            try:
                written = os.write(self._fd, self._out)
            except BlockingIOError:
                return
            except OSError as exc:
                self._lose(f"serial write failed: {exc}")
                return
            del self._out[:written]
            if not self._out:
                self._loop.remove_writer(self._fd)

    def _poison(self, reason: str) -> None:
        if self.error is None:
            self.error = reason
        self._fail_pending(DriverFault(reason))
        self._on_fault(reason)

    def _lose(self, reason: str) -> None:
        self.lost = True
        self._loop.remove_reader(self._fd)
        self._loop.remove_writer(self._fd)
        self._out.clear()
        self._poison(reason)

    def _fail_pending(self, exc: DriverFault) -> None:
        while self._pending:
            _, future = self._pending.popleft()
            if future is not None and not future.done():
                future.set_exception(exc)
                future.exception()  # mark retrieved: nobody may be waiting any more

    def send_now(self, line: bytes, within_s: float) -> bool:
        """Write one command from any thread, without the event loop; True when it went out.

        Bytes the loop still had queued go first, so the line never lands inside another;
        its reply is expected in order and dropped. Waits at most ``within_s`` for the lock
        and the port.
        """
        deadline = time.monotonic() + within_s
        if not self._write_lock.acquire(timeout=within_s):
            return False
        try:
            if self.closed or self.lost:
                return False
            data, queued = bytes(self._out) + line, bool(self._out)
            self._out.clear()
            self._pending.append((line.decode("ascii").rstrip("\r"), None))
            data = self._write_until(data, deadline)
            if data:  # the board does not take bytes: leave the rest to the loop's writer
                self._out += data
                if not queued:
                    self._loop.call_soon_threadsafe(self._loop.add_writer, self._fd,
                                                    self._on_writable)
            return not data
        finally:
            self._write_lock.release()

    def _write_until(self, data: bytes, deadline: float) -> bytes:
        """Write what the port takes before ``deadline``; the bytes left over."""
        while data:
            with contextlib.suppress(BlockingIOError):
                data = data[os.write(self._fd, data):]
            if data:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                select.select([], [self._fd], [], remaining)
        return data


# -- the driver ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class SerialSettings:
    """The ``[driver.serial]`` section: its keys, each declared once (``OPTIONS`` is made from
    them)."""

    port: str = option("/dev/ttyACM0", "serial device of the board (a udev symlink is best)")
    baudrate: int = option(BAUDRATE, "serial speed, the firmware's BAUDRATE", minval=300)
    mode: str = option("closed_loop", "closed_loop: 'm' ticks per PID frame; open_loop: 'o' raw "
                       "PWM", choices=("closed_loop", "open_loop"))
    pid_rate: float = option(PID_RATE_HZ, "the firmware's PID_RATE in Hz ('m' is ticks per frame)",
                             above=0)
    counts_per_rev: int = option(1440, "encoder counts per wheel revolution", minval=1)
    pid_p: int = option(DEFAULT_GAINS[0], "Kp sent with 'u' on open; 0 keeps the firmware's gains",
                        minval=0)
    pid_d: int = option(DEFAULT_GAINS[1], "Kd sent with 'u' on open", minval=0)
    pid_i: int = option(DEFAULT_GAINS[2], "Ki sent with 'u' on open", minval=0)
    pid_o: int = option(DEFAULT_GAINS[3], "Ko (output divisor) sent with 'u' on open", minval=1)
    max_pwm: int = option(MAX_PWM, "PWM value at full speed (open_loop)", minval=1, maxval=MAX_PWM)
    full_pwm_speed: float = option(0.0, "wheel speed in rad/s at max_pwm (open_loop); 0 = the "
                                   "robot's max wheel speed", minval=0)
    encoders: bool = option(True, "poll 'e' for wheel positions (closed-loop odometry)")
    poll_rate: float = option(0.0, "encoder polls per second; 0 = pid_rate", minval=0)
    timeout_s: float = option(0.25, "seconds to wait for a reply before faulting", above=0)
    late_host_timeout_s: float = option(1.0, "while this host is late (part of the reply came, "
                                        "the event loop woke late, or the CPUs are busy), wait "
                                        "this long in all before faulting (docs/driver-serial.md)",
                                        above=0, maxval=10.0)
    reset_wait_s: float = option(2.0, "seconds to wait after opening the port while the board "
                                 "resets, before the first byte", minval=0)
    boot_timeout_s: float = option(3.0, "then keep asking 'e' for this long until the board "
                                   "answers (a bootloader still running), s", minval=0)
    keepalive_s: float = option(0.5, "re-send a held non-zero speed after this many seconds (at "
                                "most a quarter of auto_stop_s)", above=0)
    auto_stop_s: float = option(AUTO_STOP_S, "the firmware's AUTO_STOP_INTERVAL: it stops the "
                                "motors this long after the last motor command, s (2 s in "
                                "ROSArduinoBridge as shipped; the simulated board uses this)",
                                above=0.0, maxval=60.0)
    left_motor_inverted: bool = motor_inverted("left")
    right_motor_inverted: bool = motor_inverted("right")
    left_encoder_inverted: bool = encoder_inverted("left")
    right_encoder_inverted: bool = encoder_inverted("right")


@contextlib.contextmanager
def _as_fault() -> Iterator[None]:
    """A reply that breaks the protocol faults the driver (the board or the line is bad)."""
    try:
        yield
    except ProtocolError as exc:
        raise DriverFault(str(exc)) from exc


def _read_counts(fd: int, within_s: float) -> str:
    """Read one reply line: "counts" (an answer to 'e'), "garbled", or "none" in time."""
    splitter, end = LineSplitter(), time.monotonic() + within_s
    while (left := end - time.monotonic()) > 0:
        if not select.select([fd], [], [], left)[0]:
            break
        try:
            data = os.read(fd, 256)
        except BlockingIOError:
            continue
        except OSError as exc:
            raise DriverFault(f"serial port vanished: {exc}") from None
        try:
            for raw in splitter.feed(data):
                parse_counts(decode_line(raw))
                return "counts"
        except ProtocolError:
            return "garbled"
    return "none"


class SerialBridgeDriver(MotorDriver):
    """Drives an Arduino running ROSArduinoBridge over USB serial.

    Closed loop (default): ``m L R`` in encoder ticks per PID frame; open loop: ``o L R`` raw
    PWM. Encoders are polled with ``e`` in the background; a held speed is re-sent before the
    firmware's 2 s auto-stop. A timeout, a garbled reply or a vanished port marks the driver
    faulted; ``close()`` + ``open()`` reconnects (opening resets the board, so ``open`` waits
    ``reset_wait_s``). Wheel positions stay continuous across reconnects.
    """

    SETTINGS = SerialSettings
    settings: SerialSettings

    #: how long emergency_stop() waits for the port to take ``m 0 0``
    EMERGENCY_WRITE_TIMEOUT_S = 0.1

    def __init__(self, options: Mapping[str, Any], *, max_wheel_speed: float) -> None:
        super().__init__(options, max_wheel_speed=max_wheel_speed)
        s = self.settings
        (left_motor, left_encoder), (right_motor, right_encoder) = (
            inversion_signs(s, side) for side in ("left", "right"))
        self._signs = (left_motor, right_motor)
        self._encoder_signs = (int(left_encoder), int(right_encoder))
        self._link: BridgeLink | None = None
        self._poll_task: asyncio.Task[None] | None = None
        self._wire_command = encode_command(MOTOR_SPEEDS, 0, 0)
        self._wire_sent_mono = 0.0
        #: the board answered OK to the stop on the wire: the same stop again is not written
        #: until ``_resend_every()`` has passed (a robot at rest costs no serial round trip a tick)
        self._stop_held = False
        self._last_counts: tuple[int, int] | None = None
        self._position_counts = [0, 0]
        self._reading: EncoderReading | None = None
        self.opens = 0
        self.polls = 0
        self.keepalives = 0
        self.last_rtt_s = 0.0
        self.late = LateReplies()

    # -- lifecycle ---------------------------------------------------------------------------

    async def _open(self) -> None:
        if self._link is not None:  # opened twice without close(): drop the old link first
            await self._close()
        port = await asyncio.to_thread(self._open_port)
        self.fault, self._stop_held = None, False
        try:
            await asyncio.sleep(self.settings.reset_wait_s)
            await asyncio.to_thread(self._await_boot, port)
            self._link = BridgeLink(port, self.report_fault, self.late)
            await self._handshake()
        except BaseException:
            self._drop_link() if self._link is not None else port.close()
            raise
        self.opens += 1
        self._poll_task = asyncio.create_task(self._poll_loop(), name="serial-driver-poll")

    def _open_port(self) -> Any:
        import serial  # pyserial; imported here so the module imports without it

        path = self.settings.port
        try:
            return serial.Serial(path, self.settings.baudrate, timeout=0, write_timeout=0,
                                 exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DriverFault(f"cannot open serial port {path}: {open_error(path, exc)}") \
                from None

    def _await_boot(self, port: Any) -> None:
        """Ask 'e' until the board answers with its counts: a bootloader (an Uno's takes
        1.6-2 s) drops what it hears, so the first probes may go unanswered."""
        s, fd = self.settings, port.fileno()
        deadline = time.monotonic() + s.boot_timeout_s
        attempts, garbled = 0, False
        while True:
            port.reset_input_buffer()
            os.write(fd, encode_command(READ_ENCODERS))
            attempts += 1
            answer = _read_counts(fd, s.timeout_s)
            if answer == "counts":
                break
            garbled = garbled or answer == "garbled"
            if time.monotonic() >= deadline:
                raise DriverFault(self._late_board(garbled))
        if attempts > 1:  # a late answer to an earlier probe must not reach the link
            _read_counts(fd, s.timeout_s)
            port.reset_input_buffer()

    def _late_board(self, garbled: bool) -> str:
        s = self.settings
        heard = "only garbled replies" if garbled else "no reply"
        return (f"{heard} to 'e' from the board on {s.port} within {s.reset_wait_s:g} s + "
                f"{s.boot_timeout_s:g} s after opening the port: a board that boots slower "
                f"needs a larger [driver.serial] reset_wait_s (now {s.reset_wait_s:g}); else "
                f"check baudrate ({s.baudrate}, the firmware's BAUDRATE) and that it runs "
                "ROSArduinoBridge")

    async def _handshake(self) -> None:
        """Check the board answers, take an encoder baseline, set the gains, stop the motors."""
        self._last_counts = None
        await self._poll_encoders()
        s = self.settings
        if s.pid_p > 0:
            await self._command(UPDATE_PID, encode_pid(s.pid_p, s.pid_d, s.pid_i, s.pid_o))
        await self._send_speeds(0.0, 0.0)

    async def _close(self) -> None:
        if self._poll_task is not None:
            self._poll_task.cancel()
            await asyncio.gather(self._poll_task, return_exceptions=True)
            self._poll_task = None
        if self._link is not None and self.fault is not None:
            self._stop_without_reply()
        self._drop_link()

    def _drop_link(self) -> None:
        if self._link is not None:
            self._link.close()
            self._link = None

    def _stop_without_reply(self) -> None:
        """Best effort after a fault: the port may still carry a stop the board understands."""
        if self._link is not None and not self._link.lost:
            with contextlib.suppress(DriverFault):
                self._link.send(self._stop_command())

    # -- commands ----------------------------------------------------------------------------

    async def _apply(self, left_rad_s: float, right_rad_s: float) -> None:
        if self.fault is not None:
            self._refuse_after_fault(left_rad_s, right_rad_s)
        await self._send_speeds(left_rad_s, right_rad_s)

    def _refuse_after_fault(self, left_rad_s: float, right_rad_s: float) -> None:
        if left_rad_s == 0 and right_rad_s == 0:
            self._stop_without_reply()
        raise DriverFault(f"driver faulted: {self.fault}")

    async def _send_speeds(self, left_rad_s: float, right_rad_s: float) -> None:
        line = self._speed_command(left_rad_s * self._signs[0], right_rad_s * self._signs[1])
        now = time.monotonic()
        if self._stop_held and line == self._wire_command \
                and now - self._wire_sent_mono < self._resend_every():
            return
        self._stop_held = False
        self._wire_command, self._wire_sent_mono = line, now
        await self._command(line[:1].decode("ascii"), line)
        self._stop_held = line == self._stop_command()

    def _resend_every(self) -> float:
        """How long a held command lasts on the wire before it is sent again (s)."""
        return min(self.settings.keepalive_s, self.settings.auto_stop_s / 4)

    def _speed_command(self, left: float, right: float) -> bytes:
        s = self.settings
        if s.mode == "open_loop":
            full = s.full_pwm_speed or self.max_wheel_speed
            return encode_command(MOTOR_RAW_PWM, rad_s_to_pwm(left, full, s.max_pwm),
                                  rad_s_to_pwm(right, full, s.max_pwm))
        cpr, rate = s.counts_per_rev, s.pid_rate
        return encode_command(MOTOR_SPEEDS, rad_s_to_ticks(left, cpr, rate),
                              rad_s_to_ticks(right, cpr, rate))

    def _stop_command(self) -> bytes:
        return encode_command(MOTOR_RAW_PWM if self.settings.mode == "open_loop"
                              else MOTOR_SPEEDS, 0, 0)

    async def _request(self, line: bytes) -> str:
        if self._link is None:
            raise DriverFault("serial link is not open")
        start = time.monotonic()
        reply = await self._link.request(line, self.settings.timeout_s,
                                         min(self.settings.late_host_timeout_s,
                                             self.settings.auto_stop_s / 2))
        self.last_rtt_s = time.monotonic() - start
        return reply

    async def _command(self, letter: str, line: bytes) -> None:
        """Send a command the board answers with OK."""
        reply = await self._request(line)
        with _as_fault():
            parse_ok(letter, reply)

    # -- encoders and keep-alive -------------------------------------------------------------

    def _read_encoders(self) -> EncoderReading | None:
        if not self.settings.encoders:
            return None
        if self.fault is not None:
            raise DriverFault(f"driver faulted: {self.fault}")
        return self._reading

    async def _poll_loop(self) -> None:
        period = 1.0 / (self.settings.poll_rate or self.settings.pid_rate)
        deadline = time.monotonic()
        while self.fault is None:
            deadline = max(deadline + period, time.monotonic())
            await asyncio.sleep(deadline - time.monotonic())
            try:
                if self.settings.encoders:
                    await self._poll_encoders()
                await self._keep_alive()
            except DriverFault as exc:
                self.report_fault(str(exc))

    async def _poll_encoders(self) -> None:
        sent = time.monotonic()
        reply = await self._request(encode_command(READ_ENCODERS))
        with _as_fault():
            counts = parse_counts(reply)
        self.polls += 1
        self._absorb_counts(counts, (sent + time.monotonic()) / 2)

    def _absorb_counts(self, counts: tuple[int, int], t_mono: float) -> None:
        """Accumulate counts as deltas, so a board reset or a reconnect causes no jump."""
        if self._last_counts is not None:
            for side in (0, 1):
                moved = count_delta(counts[side], self._last_counts[side])
                self._position_counts[side] += moved * self._encoder_signs[side]
        self._last_counts = counts
        cpr = self.settings.counts_per_rev
        left, right = (2 * math.pi * c / cpr for c in self._position_counts)
        self._reading = EncoderReading(left, right, t_mono)

    async def _keep_alive(self) -> None:
        """Re-send a held non-zero command before the firmware's auto-stop fires."""
        held = time.monotonic() - self._wire_sent_mono
        if self._wire_command == self._stop_command() or held < self._resend_every():
            return
        line = self._wire_command
        self._wire_sent_mono = time.monotonic()
        await self._command(line[:1].decode("ascii"), line)
        self.keepalives += 1

    def _emergency_zero(self) -> bool:
        link = self._link
        if link is None:
            return False
        stop = self._stop_command()
        self._wire_command, self._wire_sent_mono = stop, time.monotonic()  # no keep-alive
        self._stop_held = False  # no reply is read: the next tick's stop goes out again
        return link.send_now(stop, self.EMERGENCY_WRITE_TIMEOUT_S)

    def _health(self) -> dict[str, Any]:
        return {
            "port": self.settings.port,
            "mode": self.settings.mode,
            "opens": self.opens,
            "encoder_polls": self.polls,
            "keepalives": self.keepalives,
            "last_reply_ms": round(self.last_rtt_s * 1e3, 3),
            **self.late.health(),
            "wire_command": self._wire_command.decode("ascii").rstrip("\r"),
        }

