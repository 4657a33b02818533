# Emulated ODrive (two axes) answering CANSimple frames on a python-can bus, driving a MotorPair.
from __future__ import annotations

import argparse
import contextlib
import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from types import FrameType
from typing import Any

import can

from drivers.cansimple import (
    AXIS_STATE_CLOSED_LOOP_CONTROL,
    AXIS_STATE_FULL_CALIBRATION_SEQUENCE,
    AXIS_STATE_IDLE,
    CMD_CLEAR_ERRORS,
    CMD_ESTOP,
    CMD_GET_BUS_VOLTAGE_CURRENT,
    CMD_GET_ENCODER_ESTIMATES,
    CMD_GET_ERROR,
    CMD_HEARTBEAT,
    CMD_REBOOT,
    CMD_SET_AXIS_STATE,
    CMD_SET_CONTROLLER_MODE,
    CMD_SET_INPUT_VEL,
    CONTROL_MODE_POSITION,
    CONTROL_MODE_VELOCITY,
    ERROR_ESTOP_REQUESTED,
    ERROR_MOTOR_FAILED,
    ERROR_WATCHDOG_TIMER_EXPIRED,
    INPUT_MODE_PASSTHROUGH,
    FrameError,
    arbitration_id,
    decode_set_axis_state,
    decode_set_controller_mode,
    decode_set_input_vel,
    encode_bus_voltage_current,
    encode_encoder_estimates,
    encode_error,
    encode_heartbeat,
    split_arbitration_id,
)
from sim.battery import BatteryModel
from sim.motor_model import MotorPair

DEFAULT_MULTICAST_GROUP = "239.74.163.2"

FrameHook = Callable[[int, int, bytes, float], None]


@dataclass
class EmulatedAxis:
    """One ODrive axis as seen on the bus: its state machine, set-point and fault switches."""

    node_id: int
    wheel: int
    direction: int
    axis_state: int = AXIS_STATE_IDLE
    axis_error: int = 0
    error_condition: int = 0
    control_mode: int = CONTROL_MODE_POSITION
    input_mode: int = INPUT_MODE_PASSTHROUGH
    input_vel_rev_s: float = 0.0
    last_input_vel_mono: float = 0.0
    heartbeat_enabled: bool = True
    online: bool = True
    frames: dict[int, int] = field(default_factory=dict)

    def fail(self, code: int) -> None:
        """Latch an axis error; like the firmware, the axis disarms to IDLE."""
        self.axis_error |= code
        self.axis_state = AXIS_STATE_IDLE

    def drives_velocity(self) -> bool:
        return (self.axis_state == AXIS_STATE_CLOSED_LOOP_CONTROL
                and self.control_mode == CONTROL_MODE_VELOCITY)


class ODriveEmulator:
    """An ODrive on a python-can bus: heartbeat, axis states, velocity control, encoders.

    ``node_ids`` are the (left, right) axes; ``directions`` say whether positive motor turns
    move each wheel forward (+1) or backward (-1, a mirrored motor). Wheel speeds and
    positions live in ``motors`` (a :class:`MotorPair`, forward positive, rad at the wheel);
    ``gear_ratio`` is motor turns per wheel turn. One thread sends the cyclic heartbeat and
    encoder estimates and answers commands. Fault switches: :meth:`set_heartbeat`,
    :meth:`set_online`, :meth:`inject_axis_error`, :meth:`clear_error_condition`; an axis
    watchdog (``watchdog_timeout_s`` > 0) trips when Set_Input_Vel frames stop.
    """

    def __init__(self, interface: str = "virtual", channel: str = "odrive", *,
                 node_ids: Sequence[int] = (0, 1), motors: MotorPair | None = None,
                 directions: Sequence[int] = (1, -1), gear_ratio: float = 1.0,
                 heartbeat_period_s: float = 0.1, encoder_period_s: float = 0.01,
                 watchdog_timeout_s: float = 0.0,
                 bus_kwargs: dict[str, Any] | None = None) -> None:
        if len(node_ids) != 2 or node_ids[0] == node_ids[1]:
            raise ValueError(f"node_ids must be two different ids (left, right), got {node_ids}")
        self.interface, self.channel = interface, channel
        self.bus_kwargs = dict(bus_kwargs or {})
        self.motors = motors if motors is not None else MotorPair()
        self.gear_ratio = gear_ratio
        self.heartbeat_period_s = heartbeat_period_s
        self.encoder_period_s = encoder_period_s
        self.watchdog_timeout_s = watchdog_timeout_s
        self.axes = {node: EmulatedAxis(node, wheel, directions[wheel])
                     for wheel, node in enumerate(node_ids)}
        #: the pack on the DC bus (Get_Bus_Voltage_Current)
        self.battery = BatteryModel()
        self.bad_frames = 0
        self.frame_hooks: list[FrameHook] = []
        self._changed = threading.Condition()
        self._stopping = threading.Event()
        self._bus: can.BusABC | None = None
        self._thread: threading.Thread | None = None

    # -- lifecycle --------------------------------------------------------------------------

    def start(self) -> ODriveEmulator:
        self._bus = can.Bus(interface=self.interface, channel=self.channel, **self.bus_kwargs)
        self._stopping.clear()
        self._thread = threading.Thread(target=self._run, name="odrive-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def __enter__(self) -> ODriveEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def describe(self) -> str:
        left, right = self.axes.values()
        port = self.bus_kwargs.get("port")
        where = f"interface {self.interface}, channel {self.channel!r}"
        where += f", port {port}" if port is not None else ""
        return f"ODrive emulator on {where}: left node {left.node_id}, right node {right.node_id}"

    # -- fault switches ---------------------------------------------------------------------

    def set_heartbeat(self, enabled: bool, node: int | None = None) -> None:
        """Stop or resume the cyclic heartbeat (the axis keeps obeying commands)."""
        with self._changed:
            for axis in self._select(node):
                axis.heartbeat_enabled = enabled

    def set_online(self, online: bool, node: int | None = None) -> None:
        """Take a node off the bus (silent, deaf, motor coasting to a stop) or put it back."""
        with self._changed:
            for axis in self._select(node):
                axis.online = online
                if not online:
                    axis.axis_state = AXIS_STATE_IDLE
            self._update_targets()

    def inject_axis_error(self, code: int = ERROR_MOTOR_FAILED, node: int | None = None, *,
                          persistent: bool = False) -> None:
        """Latch an axis error (axis goes IDLE). ``persistent``: Clear_Errors cannot clear it
        until :meth:`clear_error_condition`."""
        with self._changed:
            for axis in self._select(node):
                axis.fail(code)
                if persistent:
                    axis.error_condition |= code
            self._update_targets()

    def clear_error_condition(self, node: int | None = None) -> None:
        """The fault's cause is gone; the latched error stays until Clear_Errors."""
        with self._changed:
            for axis in self._select(node):
                axis.error_condition = 0

    def set_running(self, vel_rev_s: float, node: int | None = None) -> None:
        """Arm the axes in velocity control at ``vel_rev_s``, as a controller that died
        mid-drive leaves them (for safe-stop tests)."""
        with self._changed:
            for axis in self._select(node):
                if axis.axis_error == 0:
                    axis.axis_state = AXIS_STATE_CLOSED_LOOP_CONTROL
                    axis.control_mode = CONTROL_MODE_VELOCITY
                    axis.input_vel_rev_s = vel_rev_s
                    axis.last_input_vel_mono = time.monotonic()
            self._update_targets()

    def _select(self, node: int | None) -> list[EmulatedAxis]:
        if node is None:
            return list(self.axes.values())
        if node not in self.axes:
            raise ValueError(f"no emulated axis with node id {node}; have {sorted(self.axes)}")
        return [self.axes[node]]

    # -- observation ------------------------------------------------------------------------

    def axis(self, side: str) -> EmulatedAxis:
        """The ``"left"`` or ``"right"`` axis."""
        wheel = {"left": 0, "right": 1}[side]
        return next(axis for axis in self.axes.values() if axis.wheel == wheel)

    def wheel_targets(self) -> tuple[float, float]:
        """Wheel speed set-points in rad/s, forward positive (what the motors are told)."""
        return self.motors.targets()

    def wait_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        """Block until ``condition()`` holds (checked after every frame) or the timeout."""
        with self._changed:
            return self._changed.wait_for(condition, timeout)

    # -- the bus thread ---------------------------------------------------------------------

    def _run(self) -> None:
        next_heartbeat = next_estimates = time.monotonic()
        while not self._stopping.is_set():
            now = time.monotonic()
            if now >= next_heartbeat:
                self._send_cyclic(CMD_HEARTBEAT)
                next_heartbeat = max(next_heartbeat + self.heartbeat_period_s, now)
            if self.encoder_period_s > 0 and now >= next_estimates:
                self._send_cyclic(CMD_GET_ENCODER_ESTIMATES)
                next_estimates = max(next_estimates + self.encoder_period_s, now)
            self._check_watchdog(now)
            due = next_heartbeat
            if self.encoder_period_s > 0:
                due = min(due, next_estimates)
            msg = self._receive(min(max(due - time.monotonic(), 0.0), 0.1))
            if msg is not None:
                self._handle(msg)

    def _receive(self, timeout: float) -> can.Message | None:
        assert self._bus is not None
        try:
            return self._bus.recv(timeout)
        except (can.CanError, OSError):
            if not self._stopping.is_set():
                time.sleep(timeout)
            return None

    def _send(self, node: int, cmd: int, data: bytes) -> None:
        assert self._bus is not None
        msg = can.Message(arbitration_id=arbitration_id(node, cmd), data=data,
                          is_extended_id=False)
        with contextlib.suppress(can.CanError, OSError):
            self._bus.send(msg, timeout=0.05)

    def _send_cyclic(self, cmd: int) -> None:
        with self._changed:
            for axis in self.axes.values():
                if not axis.online or (cmd == CMD_HEARTBEAT and not axis.heartbeat_enabled):
                    continue
                self._send(axis.node_id, cmd, self._payload(axis, cmd))
            self._changed.notify_all()

    def _payload(self, axis: EmulatedAxis, cmd: int) -> bytes:
        if cmd == CMD_HEARTBEAT:
            return encode_heartbeat(axis.axis_error, axis.axis_state)
        if cmd == CMD_GET_ERROR:
            return encode_error(axis.axis_error)
        position = self.motors.encoder_positions()[axis.wheel]
        speed = self.motors.encoder_speeds()[axis.wheel]
        scale = axis.direction * self.gear_ratio / (2 * math.pi)
        return encode_encoder_estimates(position * scale, speed * scale)

    def _check_watchdog(self, now: float) -> None:
        if self.watchdog_timeout_s <= 0:
            return
        with self._changed:
            for axis in self.axes.values():
                expired = now - axis.last_input_vel_mono > self.watchdog_timeout_s
                if axis.axis_state == AXIS_STATE_CLOSED_LOOP_CONTROL and expired:
                    axis.fail(ERROR_WATCHDOG_TIMER_EXPIRED)
                    self._update_targets()

    # -- command handling -------------------------------------------------------------------

    def _handle(self, msg: can.Message) -> None:
        if msg.is_extended_id or msg.is_error_frame:
            return
        node, cmd = split_arbitration_id(msg.arbitration_id)
        axis = self.axes.get(node)
        if axis is None or not axis.online:
            return
        now = time.monotonic()
        data = bytes(msg.data)
        with self._changed:
            if msg.is_remote_frame:
                self._answer_request(axis, cmd)
            elif not self._apply_command(axis, cmd, data, now):
                return
            axis.frames[cmd] = axis.frames.get(cmd, 0) + 1
            self._update_targets()
            self._changed.notify_all()
        for hook in list(self.frame_hooks):
            hook(node, cmd, data, now)

    def use_battery(self, battery: BatteryModel) -> None:
        """Answer Get_Bus_Voltage_Current with what ``battery`` (the simulator's pack) gives."""
        self.battery = battery

    def _answer_request(self, axis: EmulatedAxis, cmd: int) -> None:
        if cmd == CMD_GET_BUS_VOLTAGE_CURRENT:
            self._send(axis.node_id, cmd, encode_bus_voltage_current(*self.battery.measure()))
        elif cmd in (CMD_GET_ENCODER_ESTIMATES, CMD_GET_ERROR, CMD_HEARTBEAT):
            self._send(axis.node_id, cmd, self._payload(axis, cmd))

    def _apply_command(self, axis: EmulatedAxis, cmd: int, data: bytes, now: float) -> bool:
        """Act on one data frame; ``False`` for frames that are not commands to an ODrive
        (including this node's own cyclic frames echoed back) or malformed ones."""
        handler = {
            CMD_SET_INPUT_VEL: self._on_set_input_vel,
            CMD_SET_AXIS_STATE: self._on_set_axis_state,
            CMD_SET_CONTROLLER_MODE: self._on_set_controller_mode,
            CMD_CLEAR_ERRORS: self._on_clear_errors,
            CMD_ESTOP: self._on_estop,
            CMD_REBOOT: self._on_reboot,
        }.get(cmd)
        if handler is None:
            return False
        try:
            handler(axis, data, now)
        except FrameError:
            self.bad_frames += 1
            return False
        return True

    def _on_set_input_vel(self, axis: EmulatedAxis, data: bytes, now: float) -> None:
        axis.input_vel_rev_s, _torque_ff = decode_set_input_vel(data)
        axis.last_input_vel_mono = now

    def _on_set_axis_state(self, axis: EmulatedAxis, data: bytes, now: float) -> None:
        requested = decode_set_axis_state(data)
        if requested == AXIS_STATE_CLOSED_LOOP_CONTROL:
            if axis.axis_error == 0:  # the firmware refuses to arm with an error latched
                axis.axis_state = AXIS_STATE_CLOSED_LOOP_CONTROL
                axis.last_input_vel_mono = now
        elif requested in (AXIS_STATE_IDLE, AXIS_STATE_FULL_CALIBRATION_SEQUENCE):
            axis.axis_state = AXIS_STATE_IDLE  # calibration is instant here and ends in IDLE

    def _on_set_controller_mode(self, axis: EmulatedAxis, data: bytes, now: float) -> None:
        axis.control_mode, axis.input_mode = decode_set_controller_mode(data)

    def _on_clear_errors(self, axis: EmulatedAxis, data: bytes, now: float) -> None:
        axis.axis_error = axis.error_condition
        if axis.error_condition:
            axis.axis_state = AXIS_STATE_IDLE

    def _on_estop(self, axis: EmulatedAxis, data: bytes, now: float) -> None:
        axis.fail(ERROR_ESTOP_REQUESTED)

    def _on_reboot(self, axis: EmulatedAxis, data: bytes, now: float) -> None:
        axis.axis_state, axis.axis_error = AXIS_STATE_IDLE, axis.error_condition
        axis.control_mode, axis.input_mode = CONTROL_MODE_POSITION, INPUT_MODE_PASSTHROUGH
        axis.input_vel_rev_s = 0.0

    def _update_targets(self) -> None:
        targets = [0.0, 0.0]
        for axis in self.axes.values():
            if axis.online and axis.drives_velocity():
                turns_s = axis.direction * axis.input_vel_rev_s / self.gear_ratio
                targets[axis.wheel] = turns_s * 2 * math.pi
        self.motors.set_targets(targets[0], targets[1])


# -- standalone ----------------------------------------------------------------------------


class _TimeScaledClock:
    """A monotonic clock running ``scale`` times faster than real time."""

    def __init__(self, scale: float) -> None:
        self.scale, self.origin = scale, time.monotonic()

    def __call__(self) -> float:
        return self.origin + (time.monotonic() - self.origin) * self.scale


def _parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m sim.odrive_emulator",
        description="Emulated ODrive (CANSimple) on a python-can bus. Reads switch commands "
                    "on stdin: heartbeat on|off [NODE], online on|off [NODE], "
                    "error CODE [NODE] [persistent], clear-condition [NODE], "
                    "run TURNS_PER_S [NODE], status.")
    parser.add_argument("--interface", default="udp_multicast",
                        help="python-can interface (udp_multicast reaches other processes)")
    parser.add_argument("--channel", default=DEFAULT_MULTICAST_GROUP)
    parser.add_argument("--port", type=int, default=43113, help="udp_multicast UDP port")
    parser.add_argument("--left-node", type=int, default=0)
    parser.add_argument("--right-node", type=int, default=1)
    parser.add_argument("--heartbeat-period", type=float, default=0.1, help="seconds")
    parser.add_argument("--encoder-period", type=float, default=0.01,
                        help="seconds between cyclic encoder estimates (0 = only on request)")
    parser.add_argument("--gear-ratio", type=float, default=1.0)
    parser.add_argument("--watchdog", type=float, default=0.0, help="axis watchdog timeout, s")
    parser.add_argument("--time-scale", type=float, default=1.0,
                        help="run the motor model this many times faster than real time")
    return parser.parse_args(argv)


def _switch(emulator: ODriveEmulator, line: str) -> str:
    """Apply one stdin switch command; returns the reply line."""
    words = line.split()
    if not words:
        return ""
    verb, args = words[0], words[1:]
    node = None
    try:
        if verb in ("heartbeat", "online") and args and args[0] in ("on", "off"):
            node = int(args[1], 0) if len(args) > 1 else None
            setter = emulator.set_heartbeat if verb == "heartbeat" else emulator.set_online
            setter(args[0] == "on", node)
        elif verb == "error" and args:
            node = int(args[1], 0) if len(args) > 1 else None
            emulator.inject_axis_error(int(args[0], 0), node, persistent="persistent" in args)
        elif verb == "run" and args:
            emulator.set_running(float(args[0]), int(args[1], 0) if len(args) > 1 else None)
        elif verb == "clear-condition":
            emulator.clear_error_condition(int(args[0], 0) if args else None)
        elif verb == "status":
            return "ok " + "; ".join(
                f"node {a.node_id} state {a.axis_state} error {a.axis_error:#x} "
                f"vel {a.input_vel_rev_s:.3f}" for a in emulator.axes.values())
        else:
            return f"error: unknown command {line.strip()!r}"
    except ValueError as exc:
        return f"error: {exc}"
    return f"ok {line.strip()}"


def main(argv: Sequence[str] | None = None) -> int:
    args = _parse_args(argv)
    clock = _TimeScaledClock(args.time_scale)
    kwargs = {"port": args.port} if args.interface == "udp_multicast" else {}
    emulator = ODriveEmulator(
        args.interface, args.channel, node_ids=(args.left_node, args.right_node),
        motors=MotorPair(clock=clock), gear_ratio=args.gear_ratio,
        heartbeat_period_s=args.heartbeat_period, encoder_period_s=args.encoder_period,
        watchdog_timeout_s=args.watchdog, bus_kwargs=kwargs)

    def _terminate(signum: int, frame: FrameType | None) -> None:
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, _terminate)
    with emulator:
        print(emulator.describe(), flush=True)
        print(f'connect with: [driver.odrive_can] interface = "{args.interface}", '
              f'channel = "{args.channel}", multicast_port = {args.port}, '
              f"left_node_id = {args.left_node}, right_node_id = {args.right_node}", flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            for line in sys.stdin:
                reply = _switch(emulator, line)
                if reply:
                    print(reply, flush=True)
            threading.Event().wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
