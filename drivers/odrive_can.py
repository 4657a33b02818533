# ODrive CANSimple driver over python-can: velocity control, heartbeat watch, encoder odometry.
from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

import can

from base.options import option
from drivers.base import (
    DriverFault,
    EncoderReading,
    MotorDriver,
    encoder_inverted,
    inversion_signs,
    motor_inverted,
)
from drivers.cansimple import (
    AXIS_STATE_CLOSED_LOOP_CONTROL,
    AXIS_STATE_IDLE,
    CMD_CLEAR_ERRORS,
    CMD_GET_ENCODER_ESTIMATES,
    CMD_HEARTBEAT,
    CMD_SET_AXIS_STATE,
    CMD_SET_CONTROLLER_MODE,
    CMD_SET_INPUT_VEL,
    CONTROL_MODE_VELOCITY,
    INPUT_MODES,
    MAX_NODE_ID,
    EncoderEstimate,
    FrameError,
    Heartbeat,
    arbitration_id,
    axis_state_name,
    decode_encoder_estimates,
    decode_heartbeat,
    encode_set_axis_state,
    encode_set_controller_mode,
    encode_set_input_vel,
    split_arbitration_id,
)

# -- the driver --------------------------------------------------------------------------------


def _check_interface(name: str) -> str | None:
    from can.interfaces import VALID_INTERFACES

    if name in VALID_INTERFACES:
        return None
    return f"unknown python-can interface {name!r}; valid: {', '.join(sorted(VALID_INTERFACES))}"


@dataclass(frozen=True)
class ODriveSettings:
    """The ``[driver.odrive_can]`` section: its keys, each declared once (``OPTIONS`` is made from
    them)."""

    interface: str = option("socketcan", "python-can interface (socketcan on a Pi CAN HAT; "
                            "virtual or udp_multicast for the emulator)", check=_check_interface)
    channel: str = option("can0", "python-can channel (can0, a virtual bus name, or a multicast "
                          "group for udp_multicast)")
    bitrate: int = option(0, "bit rate handed to python-can (0 = the interface's own setting; "
                          "socketcan takes it from `ip link`)", minval=0)
    multicast_port: int = option(43113, "UDP port of the udp_multicast interface", minval=1,
                                 maxval=65535)
    left_node_id: int = option(0, "CAN node id of the left wheel's axis", minval=0,
                               maxval=MAX_NODE_ID)
    right_node_id: int = option(1, "CAN node id of the right wheel's axis", minval=0,
                                maxval=MAX_NODE_ID)
    # the right motor is usually mounted mirrored: its command and estimate both flip
    left_motor_inverted: bool = motor_inverted("left")
    right_motor_inverted: bool = motor_inverted("right", True)
    left_encoder_inverted: bool = encoder_inverted("left")
    right_encoder_inverted: bool = encoder_inverted("right", True)
    gear_ratio: float = option(1.0, "motor turns per wheel turn (1 for hub motors)", above=0.0)
    input_mode: str = option("passthrough", "ODrive input mode in velocity control",
                             choices=tuple(INPUT_MODES))
    heartbeat_period_s: float = option(0.1, "the ODrives' heartbeat period (heartbeat_rate_ms / "
                                       "1000)", above=0.0)
    heartbeat_misses: int = option(3, "missed heartbeat periods that make a fault", minval=1)
    encoder_timeout_s: float = option(0.5, "fault when encoder estimates stop for this long (0 = "
                                      "never)", minval=0.0)
    request_encoders: bool = option(False, "ask for encoder estimates with RTR frames (when the "
                                    "cyclic encoder message is off)")
    startup_timeout_s: float = option(2.0, "how long open() waits for heartbeats, closed loop and "
                                      "the first encoder estimates", above=0.0)
    clear_errors_on_open: bool = option(True, "send Clear_Errors before requesting closed-loop "
                                        "control")
    keepalive_period_s: float = option(0.1, "resend the last Set_Input_Vel this often to feed the "
                                       "ODrive watchdog (0 = off)", minval=0.0)
    watchdog_timeout_s: float = option(0.5, "the axis watchdog set on the ODrive "
                                       "(axis.config.watchdog_timeout, enable_watchdog = True; "
                                       "the simulated ODrive has it): the axes go idle when no "
                                       "Set_Input_Vel came for this long, s; 0 = not enabled",
                                       minval=0.0, maxval=10.0)


@dataclass
class _Axis:
    """What the driver knows about one ODrive axis (one wheel)."""

    side: str
    node_id: int
    motor_sign: float
    encoder_sign: float
    heartbeat: Heartbeat | None = None
    heartbeat_mono: float | None = None
    estimate: EncoderEstimate | None = None
    estimate_mono: float | None = None
    command_rev_s: float = 0.0

    def label(self) -> str:
        return f"ODrive node {self.node_id} ({self.side})"

    def forget(self) -> None:
        self.heartbeat = self.heartbeat_mono = self.estimate = self.estimate_mono = None
        self.command_rev_s = 0.0


class _FrameListener:
    """python-can listener on the notifier's reader thread: hands frames to the event loop.

    The notifier runs without an event loop on purpose, so it always reads in a thread of its
    own that ``stop()`` can join before the bus is shut down (no fd reader to remove from
    another thread, no receive on a closed bus).
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, on_frame: Callable[[can.Message], None],
                 on_error: Callable[[Exception], None]) -> None:
        self._loop = loop
        self._on_frame = on_frame
        self._on_error = on_error

    def __call__(self, msg: can.Message) -> None:
        self._hand_over(self._on_frame, msg)

    def on_error(self, exc: Exception) -> None:
        self._hand_over(self._on_error, exc)
        time.sleep(0.1)  # a dead interface fails every recv at once: do not spin

    def _hand_over(self, func: Callable[[Any], None], arg: Any) -> None:
        with contextlib.suppress(RuntimeError):  # the loop is already closed
            self._loop.call_soon_threadsafe(func, arg)


class ODriveCanDriver(MotorDriver):
    """Two ODrive axes (one per wheel) driven with CANSimple frames over python-can.

    ``open()`` waits for both heartbeats, clears errors, zeroes the velocity input, selects
    velocity control and requests closed-loop control, then waits until both heartbeats report
    it and the first encoder estimates arrived. A background task turns a missing heartbeat, an
    axis error, an axis leaving closed loop or stale encoder estimates into a fault (and zeroes
    the velocity inputs at once). ``close()`` zeroes the inputs and puts both axes in IDLE.
    """

    SETTINGS = ODriveSettings
    settings: ODriveSettings

    SEND_TIMEOUT_S = 0.05

    def __init__(self, options: Mapping[str, Any], *, max_wheel_speed: float) -> None:
        super().__init__(options, max_wheel_speed=max_wheel_speed)
        s = self.settings
        problems = self.check_options(asdict(s))
        if problems:
            raise ValueError("; ".join(problems))
        self._left = _Axis("left", s.left_node_id, *inversion_signs(s, "left"))
        self._right = _Axis("right", s.right_node_id, *inversion_signs(s, "right"))
        self._axes = {axis.node_id: axis for axis in (self._left, self._right)}
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._frame_event: asyncio.Event | None = None
        self.frames_rx = 0
        self.frames_tx = 0
        self.bad_frames = 0
        self.last_bad_frame = ""

    @classmethod
    def check_options(cls, values: Mapping[str, Any]) -> list[str]:
        """Problems between keys of an otherwise valid ``[driver.odrive_can]`` section."""
        left, right = values.get("left_node_id", 0), values.get("right_node_id", 1)
        if left == right:
            return [f"[driver.odrive_can] left_node_id and right_node_id must differ "
                    f"(both are {left})"]
        watchdog = values.get("watchdog_timeout_s", 0.5)
        keepalive = values.get("keepalive_period_s", 0.1)
        if watchdog > 0 and keepalive > watchdog / 2:
            return [f"[driver.odrive_can] keepalive_period_s = {keepalive:g} must be at most "
                    f"half of watchdog_timeout_s = {watchdog:g}, or the watchdog trips while the "
                    "daemon runs"]
        return []

    # -- unit conversion --------------------------------------------------------------------

    def _rad_to_rev(self, axis: _Axis, rad: float) -> float:
        return axis.motor_sign * rad * self.settings.gear_ratio / (2 * math.pi)

    def _rev_to_rad(self, axis: _Axis, rev: float) -> float:
        return axis.encoder_sign * rev * 2 * math.pi / self.settings.gear_ratio

    # -- lifecycle --------------------------------------------------------------------------

    async def _open(self) -> None:
        for axis in self._axes.values():
            axis.forget()
        self._frame_event = asyncio.Event()
        self._bus = await asyncio.to_thread(self._connect)
        try:
            listener = _FrameListener(asyncio.get_running_loop(), self._on_frame,
                                      self._on_receive_error)
            self._notifier = can.Notifier(self._bus, [listener], timeout=0.1)
            await self._start_axes()
        except BaseException:
            await self._release_bus(idle=True)
            raise
        self._tasks = [asyncio.create_task(self._monitor(), name="odrive-monitor")]
        if self.settings.keepalive_period_s > 0:
            self._tasks.append(asyncio.create_task(self._keepalive(), name="odrive-keepalive"))

    def _connect(self) -> can.BusABC:
        kwargs: dict[str, Any] = {}
        if self.settings.bitrate:
            kwargs["bitrate"] = self.settings.bitrate
        if self.settings.interface == "udp_multicast":
            kwargs["port"] = self.settings.multicast_port
        return can.Bus(interface=self.settings.interface, channel=self.settings.channel,
                       **kwargs)

    async def _start_axes(self) -> None:
        axes = list(self._axes.values())
        await self._wait_until(lambda: all(a.heartbeat is not None for a in axes),
                               "a heartbeat")
        input_mode = INPUT_MODES[self.settings.input_mode]
        for axis in axes:
            if self.settings.clear_errors_on_open:
                self._send(axis, CMD_CLEAR_ERRORS, b"\x00")
            # zero the set-point first: entering closed loop must not resume an old velocity
            self._send(axis, CMD_SET_INPUT_VEL, encode_set_input_vel(0.0))
            self._send(axis, CMD_SET_CONTROLLER_MODE,
                       encode_set_controller_mode(CONTROL_MODE_VELOCITY, input_mode))
            self._send(axis, CMD_SET_AXIS_STATE, encode_set_axis_state(
                AXIS_STATE_CLOSED_LOOP_CONTROL))
        await self._wait_until(lambda: all(_in_closed_loop(a) for a in axes),
                               "closed-loop control")
        self._request_estimates()
        await self._wait_until(lambda: all(a.estimate is not None for a in axes),
                               "encoder estimates", poke=self._request_estimates)

    async def _wait_until(self, done: Callable[[], bool], what: str,
                          poke: Callable[[], None] | None = None) -> None:
        assert self._frame_event is not None
        deadline = time.monotonic() + self.settings.startup_timeout_s
        while not done():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DriverFault(f"waited {self.settings.startup_timeout_s} s for {what} on "
                                  f"{self._where()}: {self._axes_summary()}")
            self._frame_event.clear()
            with contextlib.suppress(TimeoutError):  # not wait_for: it may swallow a cancel
                async with asyncio.timeout(min(remaining, 0.1)):
                    await self._frame_event.wait()
            if poke is not None:
                poke()

    async def _close(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._tasks = []
        await self._release_bus(idle=True)

    async def _release_bus(self, *, idle: bool) -> None:
        bus, notifier = self._bus, self._notifier
        self._bus = self._notifier = None
        if bus is None:
            return
        if idle:
            self._zero_and_idle(bus)
        if notifier is not None:
            await asyncio.to_thread(notifier.stop, 1.0)
        await asyncio.to_thread(bus.shutdown)

    def _zero_and_idle(self, bus: can.BusABC) -> None:
        """Best effort: zero velocity and IDLE on both axes, ignoring send errors."""
        for axis in self._axes.values():
            for cmd, data in ((CMD_SET_INPUT_VEL, encode_set_input_vel(0.0)),
                              (CMD_SET_AXIS_STATE, encode_set_axis_state(AXIS_STATE_IDLE))):
                with contextlib.suppress(can.CanError, OSError):
                    bus.send(_frame(axis.node_id, cmd, data), timeout=self.SEND_TIMEOUT_S)
                    self.frames_tx += 1

    async def safe_stop(self) -> None:
        """Zero both velocity inputs and put both axes in IDLE, without entering closed loop."""
        try:
            bus = await asyncio.to_thread(self._connect)
        except (can.CanError, OSError, ValueError) as exc:
            raise DriverFault(f"safe-stop: cannot open {self._where()}: {exc}") from exc
        try:
            self._zero_and_idle(bus)
            idle = await asyncio.to_thread(self._confirm_idle, bus)
        finally:
            await asyncio.to_thread(bus.shutdown)
        missing = [a.label() for a in self._axes.values() if a.node_id not in idle]
        if missing:
            raise DriverFault(f"safe-stop sent zero velocity and IDLE on {self._where()}, but "
                              f"no IDLE heartbeat came back from {', '.join(missing)}")

    def _confirm_idle(self, bus: can.BusABC) -> set[int]:
        window = self.settings.heartbeat_period_s * (self.settings.heartbeat_misses + 1)
        deadline = time.monotonic() + window
        idle: set[int] = set()
        while idle != set(self._axes) and (remaining := deadline - time.monotonic()) > 0:
            msg = bus.recv(remaining)
            if msg is None or msg.is_remote_frame or msg.is_extended_id:
                continue
            node, cmd = split_arbitration_id(msg.arbitration_id)
            if node in self._axes and cmd == CMD_HEARTBEAT:
                with contextlib.suppress(FrameError):
                    if decode_heartbeat(bytes(msg.data)).axis_state == AXIS_STATE_IDLE:
                        idle.add(node)
        return idle

    # -- commands ---------------------------------------------------------------------------

    async def _apply(self, left_rad_s: float, right_rad_s: float) -> None:
        moving = left_rad_s != 0.0 or right_rad_s != 0.0
        reason = self.fault or self._link_fault(time.monotonic())
        if reason and moving:
            self.report_fault(reason)
            raise DriverFault(reason)
        for axis, rad_s in ((self._left, left_rad_s), (self._right, right_rad_s)):
            rev_s = self._rad_to_rev(axis, rad_s)
            self._send(axis, CMD_SET_INPUT_VEL, encode_set_input_vel(rev_s))
            axis.command_rev_s = rev_s

    def _read_encoders(self) -> EncoderReading | None:
        if self.settings.request_encoders:
            self._request_estimates()
        left, right = self._left, self._right
        if left.estimate is None or right.estimate is None:
            raise DriverFault(f"no encoder estimates yet on {self._where()}")
        t_mono = max(left.estimate_mono or 0.0, right.estimate_mono or 0.0)
        return EncoderReading(self._rev_to_rad(left, left.estimate.pos_rev),
                              self._rev_to_rad(right, right.estimate.pos_rev), t_mono)

    def _request_estimates(self) -> None:
        if self.settings.request_encoders:
            for axis in self._axes.values():
                self._send(axis, CMD_GET_ENCODER_ESTIMATES, b"", remote=True)

    def _send(self, axis: _Axis, cmd: int, data: bytes, *, remote: bool = False) -> None:
        if self._bus is None:
            raise DriverFault("CAN bus is not open")
        try:
            self._bus.send(_frame(axis.node_id, cmd, data, remote=remote),
                           timeout=self.SEND_TIMEOUT_S)
        except (can.CanError, OSError) as exc:
            raise DriverFault(f"CAN send of command {cmd:#04x} to {axis.label()} on "
                              f"{self._where()} failed: {exc}") from exc
        self.frames_tx += 1

    # -- receive path and supervision --------------------------------------------------------

    def _on_frame(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_extended_id or msg.is_remote_frame:
            return
        node, cmd = split_arbitration_id(msg.arbitration_id)
        axis = self._axes.get(node)
        if axis is None or cmd not in (CMD_HEARTBEAT, CMD_GET_ENCODER_ESTIMATES):
            return
        self.frames_rx += 1
        try:
            if cmd == CMD_HEARTBEAT:
                axis.heartbeat = decode_heartbeat(bytes(msg.data))
                axis.heartbeat_mono = time.monotonic()
            else:
                axis.estimate = decode_encoder_estimates(bytes(msg.data))
                axis.estimate_mono = time.monotonic()
        except FrameError as exc:
            self.bad_frames += 1
            self.last_bad_frame = f"{axis.label()}, id {msg.arbitration_id:#05x}: {exc}"
            return
        if self._frame_event is not None:
            self._frame_event.set()

    def _on_receive_error(self, exc: Exception) -> None:
        if self._bus is not None:  # errors of a bus being shut down are no fault
            self.report_fault(f"CAN receive on {self._where()} failed: {exc}")

    def _link_fault(self, now: float) -> str | None:
        """Why the ODrives cannot be trusted right now, or ``None``."""
        limit = self.settings.heartbeat_period_s * self.settings.heartbeat_misses
        encoder_limit = self.settings.encoder_timeout_s
        for axis in self._axes.values():
            age = now - (axis.heartbeat_mono or 0.0)
            if axis.heartbeat is None or age > limit:
                return (f"no heartbeat from {axis.label()} for {age * 1e3:.0f} ms "
                        f"(limit {limit * 1e3:.0f} ms)")
            if axis.heartbeat.axis_error:
                return (f"{axis.label()} reports axis error {axis.heartbeat.axis_error:#010x} "
                        f"in state {axis_state_name(axis.heartbeat.axis_state)}")
            if axis.heartbeat.axis_state != AXIS_STATE_CLOSED_LOOP_CONTROL:
                return (f"{axis.label()} left closed-loop control "
                        f"(axis state {axis_state_name(axis.heartbeat.axis_state)})")
            estimate_age = now - (axis.estimate_mono or 0.0)
            if encoder_limit > 0 and estimate_age > encoder_limit:
                return (f"no encoder estimates from {axis.label()} for "
                        f"{estimate_age * 1e3:.0f} ms (limit {encoder_limit * 1e3:.0f} ms)")
        return None

    async def _monitor(self) -> None:
        period = self.settings.heartbeat_period_s / 2
        while True:
            await asyncio.sleep(period)
            reason = self._link_fault(time.monotonic())
            if reason and self.fault is None:
                self.report_fault(reason)
                if self._bus is not None:
                    self._zero_inputs(self._bus)

    def _zero_inputs(self, bus: can.BusABC) -> None:
        for axis in self._axes.values():
            axis.command_rev_s = 0.0
            with contextlib.suppress(can.CanError, OSError):
                bus.send(_frame(axis.node_id, CMD_SET_INPUT_VEL, encode_set_input_vel(0.0)),
                         timeout=self.SEND_TIMEOUT_S)
                self.frames_tx += 1

    async def _keepalive(self) -> None:
        period = self.settings.keepalive_period_s
        while True:
            await asyncio.sleep(period)
            if self.fault is not None:
                continue
            try:
                for axis in self._axes.values():
                    self._send(axis, CMD_SET_INPUT_VEL, encode_set_input_vel(axis.command_rev_s))
            except DriverFault as exc:
                self.report_fault(str(exc))

    # -- reporting --------------------------------------------------------------------------

    def _where(self) -> str:
        return f"{self.settings.interface} channel {self.settings.channel!r}"

    def _axes_summary(self) -> str:
        parts = []
        for axis in self._axes.values():
            hb = axis.heartbeat
            if hb is None:
                parts.append(f"{axis.label()}: no heartbeat")
            else:
                parts.append(f"{axis.label()}: state {axis_state_name(hb.axis_state)}, "
                             f"axis error {hb.axis_error:#010x}, "
                             f"encoder estimates {'yes' if axis.estimate else 'none'}")
        return "; ".join(parts)

    def _health(self) -> dict[str, Any]:
        now = time.monotonic()
        return {
            "interface": self.settings.interface,
            "channel": self.settings.channel,
            "frames_rx": self.frames_rx,
            "frames_tx": self.frames_tx,
            "bad_frames": self.bad_frames,
            "last_bad_frame": self.last_bad_frame,
            "axes": {axis.side: _axis_health(axis, now) for axis in self._axes.values()},
        }

    # -- emergency path (any thread) ---------------------------------------------------------

    def _emergency_zero(self) -> bool:
        """Set_Input_Vel 0 to both axes, straight onto the bus, each send bounded.

        No lock is needed: python-can's send is safe from several threads on the interfaces
        used here (socketcan and udp_multicast send one datagram per frame; virtual puts a
        copy on each peer's thread-safe queue), and each frame is complete on its own.
        """
        bus = self._bus
        if bus is None:
            return False
        sent = 0
        for axis in self._axes.values():
            axis.command_rev_s = 0.0  # the keep-alive re-sends zero from now on
            with contextlib.suppress(can.CanError, OSError):
                bus.send(_frame(axis.node_id, CMD_SET_INPUT_VEL, encode_set_input_vel(0.0)),
                         timeout=self.SEND_TIMEOUT_S)
                sent += 1
        self.frames_tx += sent
        return sent == len(self._axes)


def _axis_health(axis: _Axis, now: float) -> dict[str, Any]:
    hb = axis.heartbeat
    return {
        "node_id": axis.node_id,
        "axis_state": axis_state_name(hb.axis_state) if hb else None,
        "axis_error": f"{hb.axis_error:#010x}" if hb else None,
        "heartbeat_age_ms": round((now - axis.heartbeat_mono) * 1e3, 1)
        if axis.heartbeat_mono is not None else None,
        "encoder_age_ms": round((now - axis.estimate_mono) * 1e3, 1)
        if axis.estimate_mono is not None else None,
        "input_vel_rev_s": axis.command_rev_s,
    }


def _in_closed_loop(axis: _Axis) -> bool:
    hb = axis.heartbeat
    return hb is not None and hb.axis_error == 0 and hb.axis_state == AXIS_STATE_CLOSED_LOOP_CONTROL


def _frame(node_id: int, cmd: int, data: bytes, *, remote: bool = False) -> can.Message:
    if remote:
        return can.Message(arbitration_id=arbitration_id(node_id, cmd), is_extended_id=False,
                           is_remote_frame=True, dlc=8)
    return can.Message(arbitration_id=arbitration_id(node_id, cmd), data=data,
                       is_extended_id=False)
