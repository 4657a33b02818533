# ODrive CANSimple wire format (pure, no I/O): ids, states, payloads; shared by driver and emulator.
from __future__ import annotations

import math
import struct
from dataclasses import dataclass

# command ids (firmware 0.5 / 0.6 numbering)
CMD_HEARTBEAT = 0x01
CMD_ESTOP = 0x02
CMD_GET_ERROR = 0x03
CMD_SET_AXIS_STATE = 0x07
CMD_GET_ENCODER_ESTIMATES = 0x09
CMD_SET_CONTROLLER_MODE = 0x0B
CMD_SET_INPUT_VEL = 0x0D
CMD_REBOOT = 0x16
CMD_GET_BUS_VOLTAGE_CURRENT = 0x17
CMD_CLEAR_ERRORS = 0x18

AXIS_STATE_IDLE = 1
AXIS_STATE_FULL_CALIBRATION_SEQUENCE = 3
AXIS_STATE_CLOSED_LOOP_CONTROL = 8
CONTROL_MODE_VELOCITY = 2
CONTROL_MODE_POSITION = 3
INPUT_MODE_PASSTHROUGH = 1
INPUT_MODES = {"passthrough": INPUT_MODE_PASSTHROUGH, "vel_ramp": 2}

# axis error bits of firmware 0.5
ERROR_MOTOR_FAILED = 0x40
ERROR_WATCHDOG_TIMER_EXPIRED = 0x800
ERROR_ESTOP_REQUESTED = 0x4000

AXIS_STATE_NAMES = {
    0: "UNDEFINED", 1: "IDLE", 2: "STARTUP_SEQUENCE", 3: "FULL_CALIBRATION_SEQUENCE",
    4: "MOTOR_CALIBRATION", 6: "ENCODER_INDEX_SEARCH", 7: "ENCODER_OFFSET_CALIBRATION",
    8: "CLOSED_LOOP_CONTROL", 9: "LOCKIN_SPIN", 10: "ENCODER_DIR_FIND", 11: "HOMING",
}

MAX_NODE_ID = 0x3F
MAX_CMD_ID = 0x1F

_HEARTBEAT = struct.Struct("<IBBBx")  # axis error, axis state, procedure result, trajectory done
_TWO_FLOATS = struct.Struct("<ff")
_UINT32 = struct.Struct("<I")
_TWO_UINT32 = struct.Struct("<II")


class FrameError(ValueError):
    """A CANSimple frame whose id or payload does not fit the protocol."""


@dataclass(frozen=True)
class Heartbeat:
    """The part of the cyclic heartbeat the driver uses (bytes 0-3 error, byte 4 state)."""

    axis_error: int
    axis_state: int


@dataclass(frozen=True)
class EncoderEstimate:
    """A Get_Encoder_Estimates payload: position in turns and velocity in turns/s."""

    pos_rev: float
    vel_rev_s: float


def arbitration_id(node_id: int, cmd_id: int) -> int:
    """The 11-bit CAN id of a command: ``node_id << 5 | cmd_id``."""
    if not 0 <= node_id <= MAX_NODE_ID:
        raise FrameError(f"node id must be 0..{MAX_NODE_ID}, got {node_id}")
    if not 0 <= cmd_id <= MAX_CMD_ID:
        raise FrameError(f"command id must be 0..{MAX_CMD_ID:#x}, got {cmd_id:#x}")
    return node_id << 5 | cmd_id


def split_arbitration_id(arb_id: int) -> tuple[int, int]:
    """(node id, command id) of an 11-bit CANSimple id."""
    if not 0 <= arb_id <= 0x7FF:
        raise FrameError(f"CANSimple uses 11-bit ids, got {arb_id:#x}")
    return arb_id >> 5, arb_id & MAX_CMD_ID


def axis_state_name(state: int) -> str:
    return AXIS_STATE_NAMES.get(state, f"STATE_{state}")


# -- host -> ODrive ------------------------------------------------------------------------


def encode_set_input_vel(vel_rev_s: float, torque_ff_nm: float = 0.0) -> bytes:
    """Set_Input_Vel payload: two little-endian float32, velocity [turn/s] and torque [Nm]."""
    if not (math.isfinite(vel_rev_s) and math.isfinite(torque_ff_nm)):
        raise FrameError(f"Set_Input_Vel needs finite values, got {vel_rev_s}, {torque_ff_nm}")
    return _TWO_FLOATS.pack(vel_rev_s, torque_ff_nm)


def decode_set_input_vel(data: bytes) -> tuple[float, float]:
    """(velocity turn/s, torque feed-forward Nm) of a Set_Input_Vel; the velocity must be finite."""
    vel, torque = _unpack(_TWO_FLOATS, data, "Set_Input_Vel")
    if not math.isfinite(vel):
        raise FrameError(f"Set_Input_Vel velocity (bytes 0-3) is not finite: {vel}")
    return vel, torque


def encode_set_axis_state(state: int) -> bytes:
    """Set_Axis_State payload: the requested state as little-endian uint32."""
    return _UINT32.pack(state)


def decode_set_axis_state(data: bytes) -> int:
    (state,) = _unpack(_UINT32, data, "Set_Axis_State")
    return int(state)


def encode_set_controller_mode(control_mode: int, input_mode: int) -> bytes:
    """Set_Controller_Mode payload: control mode and input mode as little-endian uint32."""
    return _TWO_UINT32.pack(control_mode, input_mode)


def decode_set_controller_mode(data: bytes) -> tuple[int, int]:
    """(control mode, input mode) of a Set_Controller_Mode."""
    control_mode, input_mode = _unpack(_TWO_UINT32, data, "Set_Controller_Mode")
    return int(control_mode), int(input_mode)


# -- ODrive -> host ------------------------------------------------------------------------


def encode_heartbeat(axis_error: int, axis_state: int, procedure_result: int = 0,
                     trajectory_done: bool = True) -> bytes:
    """The 8-byte cyclic heartbeat: axis error, axis state, procedure result, trajectory done."""
    return _HEARTBEAT.pack(axis_error, axis_state, procedure_result, int(trajectory_done))


def decode_heartbeat(data: bytes) -> Heartbeat:
    """Parse a heartbeat; only the axis error (bytes 0-3) and state (byte 4) are needed."""
    if len(data) < 5:
        raise FrameError(f"heartbeat needs at least 5 data bytes, got {len(data)}")
    axis_error, axis_state = struct.unpack_from("<IB", data)
    return Heartbeat(axis_error, axis_state)


def encode_encoder_estimates(pos_rev: float, vel_rev_s: float) -> bytes:
    """Get_Encoder_Estimates payload: position [turn] and velocity [turn/s], float32."""
    return _TWO_FLOATS.pack(pos_rev, vel_rev_s)


def decode_encoder_estimates(data: bytes) -> EncoderEstimate:
    """Parse Get_Encoder_Estimates: position (bytes 0-3) and velocity (bytes 4-7), float32."""
    if len(data) < 8:
        raise FrameError(f"encoder estimates need 8 data bytes, got {len(data)}")
    pos, vel = _TWO_FLOATS.unpack_from(data)
    if not math.isfinite(pos):
        raise FrameError(f"encoder position (bytes 0-3) is not finite: {pos}")
    if not math.isfinite(vel):
        raise FrameError(f"encoder velocity (bytes 4-7) is not finite: {vel}")
    return EncoderEstimate(pos, vel)


def encode_error(active_errors: int, disarm_reason: int = 0) -> bytes:
    """Get_Error payload: active errors and disarm reason, little-endian uint32."""
    return _TWO_UINT32.pack(active_errors, disarm_reason)


def _unpack(layout: struct.Struct, data: bytes, what: str) -> tuple[float | int, ...]:
    if len(data) < layout.size:
        raise FrameError(f"{what} needs {layout.size} data bytes, got {len(data)}")
    return layout.unpack_from(data)


def encode_bus_voltage_current(volts: float, amps: float) -> bytes:
    """Get_Bus_Voltage_Current's answer: the DC bus voltage (V) and current (A, positive drawn)."""
    return _TWO_FLOATS.pack(volts, amps)


def decode_bus_voltage_current(data: bytes) -> tuple[float, float]:
    volts, amps = _unpack(_TWO_FLOATS, data, "Get_Bus_Voltage_Current")
    return float(volts), float(amps)
