# RPLIDAR requests and single replies: codes, framing, descriptors, INFO/HEALTH/... (pure, no I/O).
from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

SYNC = 0xA5
DESCRIPTOR_SYNC = b"\xa5\x5a"
DESCRIPTOR_SIZE = 7
BANNER_PREFIX = b"RP LIDAR System"


class Cmd(IntEnum):
    """Request codes (commands with bit 7 set carry a payload)."""

    STOP = 0x25
    RESET = 0x40
    SCAN = 0x20
    FORCE_SCAN = 0x21
    EXPRESS_SCAN = 0x82
    HQ_SCAN = 0x83
    GET_INFO = 0x50
    GET_HEALTH = 0x52
    GET_SAMPLERATE = 0x59
    GET_LIDAR_CONF = 0x84
    SET_LIDAR_CONF = 0x85
    SET_MOTOR_PWM = 0xF0
    HQ_MOTOR_SPEED_CTRL = 0xA8
    GET_ACC_BOARD_FLAG = 0xFF
    NEW_BAUDRATE_CONFIRM = 0x90


class Ans(IntEnum):
    """Reply data types (the last descriptor byte)."""

    INFO = 0x04
    HEALTH = 0x06
    SAMPLERATE = 0x15
    LIDAR_CONF = 0x20
    SET_LIDAR_CONF = 0x21
    ACC_BOARD_FLAG = 0xFF
    NODE = 0x81
    CAPSULE = 0x82
    HQ_CAPSULE = 0x83
    ULTRA_CAPSULE = 0x84
    DENSE_CAPSULE = 0x85
    ULTRA_DENSE_CAPSULE = 0x86


class Conf(IntEnum):
    """GET_LIDAR_CONF types."""

    SCAN_MODE_COUNT = 0x70
    SCAN_MODE_US_PER_SAMPLE = 0x71
    SCAN_MODE_MAX_DISTANCE = 0x74
    SCAN_MODE_ANS_TYPE = 0x75
    SCAN_MODE_TYPICAL = 0x7C
    SCAN_MODE_NAME = 0x7F
    DESIRED_ROT_FREQ = 0x01
    SCAN_MODE_ALIAS = 0x81
    DETECTED_BAUDRATE = 0xA1


# (length, multi-response) for replies the parser knows; None length = variable (bounded).
_REPLY_SHAPES: dict[int, tuple[int | None, bool]] = {
    Ans.INFO: (20, False), Ans.HEALTH: (3, False), Ans.SAMPLERATE: (4, False),
    Ans.LIDAR_CONF: (None, False), Ans.SET_LIDAR_CONF: (None, False),
    Ans.ACC_BOARD_FLAG: (4, False), Ans.NODE: (5, True), Ans.CAPSULE: (84, True),
    Ans.HQ_CAPSULE: (781, True), Ans.ULTRA_CAPSULE: (132, True), Ans.DENSE_CAPSULE: (84, True),
    Ans.ULTRA_DENSE_CAPSULE: (170, True),
}
_MAX_VARIABLE_REPLY = 256

# ---------------------------------------------------------------- request encoder


def request(cmd: int, payload: bytes = b"") -> bytes:
    """Encode a request; commands with bit 7 set get size, payload and an XOR checksum."""
    if not cmd & 0x80:
        if payload:
            raise ValueError(f"command 0x{cmd:02X} takes no payload, got {len(payload)} bytes")
        return bytes((SYNC, cmd))
    if len(payload) > 255:
        raise ValueError(f"payload of command 0x{cmd:02X} is {len(payload)} bytes (max 255)")
    frame = bytes((SYNC, cmd, len(payload))) + payload
    checksum = 0
    for byte in frame:
        checksum ^= byte
    return frame + bytes((checksum,))


def stop() -> bytes:
    return request(Cmd.STOP)


def reset() -> bytes:
    return request(Cmd.RESET)


def scan() -> bytes:
    return request(Cmd.SCAN)


def force_scan() -> bytes:
    return request(Cmd.FORCE_SCAN)


def express_scan(working_mode: int = 0, flags: int = 0, param: int = 0) -> bytes:
    return request(Cmd.EXPRESS_SCAN, struct.pack("<BHH", working_mode, flags, param))


def hq_scan(flag: int = 0) -> bytes:
    return request(Cmd.HQ_SCAN, bytes((flag,)) + bytes(32))


def get_info() -> bytes:
    return request(Cmd.GET_INFO)


def get_health() -> bytes:
    return request(Cmd.GET_HEALTH)


def get_samplerate() -> bytes:
    return request(Cmd.GET_SAMPLERATE)


def get_lidar_conf(conf_type: int, mode: int | None = None) -> bytes:
    extra = b"" if mode is None else struct.pack("<H", mode)
    return request(Cmd.GET_LIDAR_CONF, struct.pack("<I", conf_type) + extra)


def set_lidar_conf(conf_type: int, data: bytes) -> bytes:
    return request(Cmd.SET_LIDAR_CONF, struct.pack("<I", conf_type) + data)


def set_motor_pwm(pwm: int) -> bytes:
    if not 0 <= pwm <= 1023:
        raise ValueError(f"motor PWM must be 0..1023, got {pwm}")
    return request(Cmd.SET_MOTOR_PWM, struct.pack("<H", pwm))


def hq_motor_speed(rpm: int) -> bytes:
    if not 0 <= rpm <= 0xFFFF:
        raise ValueError(f"motor rpm must be 0..65535, got {rpm}")
    return request(Cmd.HQ_MOTOR_SPEED_CTRL, struct.pack("<H", rpm))


def get_acc_board_flag() -> bytes:
    return request(Cmd.GET_ACC_BOARD_FLAG, struct.pack("<I", 0))


def new_baudrate_confirm(bps: int) -> bytes:
    return request(Cmd.NEW_BAUDRATE_CONFIRM, struct.pack("<HIH", 0x5F5F, bps, 0))


def parse_request(frame: bytes) -> tuple[int, bytes] | None:
    """Decode one request frame (for emulators): (cmd, payload), or None when malformed."""
    if len(frame) < 2 or frame[0] != SYNC:
        return None
    cmd = frame[1]
    if not cmd & 0x80:
        return (cmd, b"") if len(frame) == 2 else None
    if len(frame) < 4 or len(frame) != frame[2] + 4:
        return None
    return (cmd, frame[3:-1]) if request(cmd, frame[3:-1]) == frame else None


# ---------------------------------------------------------------- single replies


@dataclass(frozen=True)
class Descriptor:
    length: int
    multi: bool
    data_type: int

    def encode(self) -> bytes:
        word = (self.length & 0x3FFFFFFF) | ((1 if self.multi else 0) << 30)
        return DESCRIPTOR_SYNC + struct.pack("<IB", word, self.data_type)


@dataclass(frozen=True)
class DeviceInfo:
    model: int
    firmware_major: int
    firmware_minor: int
    hardware: int
    serial: str  # uppercase hex, in byte order

    @property
    def firmware(self) -> str:
        return f"{self.firmware_major}.{self.firmware_minor:02d}"

    @property
    def firmware_version(self) -> tuple[int, int]:
        return (self.firmware_major, self.firmware_minor)

    @property
    def family(self) -> str:
        return model_family(self.model)

    @property
    def model_name(self) -> str:
        return f"{self.family}M{self.model & 0xF}"


@dataclass(frozen=True)
class Health:
    status: int  # 0 ok, 1 warning, 2 error (protection stop)
    error_code: int

    @property
    def status_name(self) -> str:
        return {0: "ok", 1: "warning", 2: "error"}.get(self.status, f"unknown({self.status})")


@dataclass(frozen=True)
class SampleRate:
    standard_us: int
    express_us: int


@dataclass(frozen=True)
class LidarConf:
    conf_type: int
    data: bytes

    def as_int(self) -> int:
        return int.from_bytes(self.data[:4], "little")

    def as_name(self) -> str:
        return self.data.split(b"\x00", 1)[0].decode("ascii", "replace")


@dataclass(frozen=True)
class AccBoardFlag:
    flags: int

    @property
    def has_pwm(self) -> bool:
        return bool(self.flags & 1)


@dataclass(frozen=True)
class RawReply:
    """A single reply of a known type the parser does not interpret (e.g. SET_LIDAR_CONF)."""

    data_type: int
    data: bytes


Reply = DeviceInfo | Health | SampleRate | LidarConf | AccBoardFlag | RawReply


def model_family(model: int) -> str:
    """Model byte → family name (A1..A3, C, S1..S3, T) following the SDK's major numbers."""
    major = model >> 4
    families = {1: "A1", 2: "A2", 3: "A3", 4: "C1", 5: "C", 6: "S1", 7: "S2", 8: "S3"}
    return families.get(major, "T" if major >= 9 else f"unknown(0x{model:02X})")


def parse_descriptor(raw: bytes) -> Descriptor | None:
    """A 7-byte descriptor of a known reply type with a consistent length, or None."""
    if len(raw) < DESCRIPTOR_SIZE or raw[:2] != DESCRIPTOR_SYNC:
        return None
    word, data_type = struct.unpack_from("<IB", raw, 2)
    desc = Descriptor(word & 0x3FFFFFFF, bool(word >> 30 & 1), data_type)
    shape = _REPLY_SHAPES.get(data_type)
    if shape is None or word >> 31:
        return None
    length, multi = shape
    if multi != desc.multi:
        return None
    if length is None:
        return desc if 4 <= desc.length <= _MAX_VARIABLE_REPLY else None
    return desc if desc.length == length else None


def parse_reply(desc: Descriptor, data: bytes) -> Reply:
    """Interpret the body of a single reply."""
    if desc.data_type == Ans.INFO:
        model, fw_minor, fw_major, hw = struct.unpack_from("<BBBB", data)
        return DeviceInfo(model, fw_major, fw_minor, hw, data[4:20].hex().upper())
    if desc.data_type == Ans.HEALTH:
        status, code = struct.unpack_from("<BH", data)
        return Health(status, code)
    if desc.data_type == Ans.SAMPLERATE:
        return SampleRate(*struct.unpack_from("<HH", data))
    if desc.data_type == Ans.LIDAR_CONF:
        return LidarConf(struct.unpack_from("<I", data)[0], bytes(data[4:]))
    if desc.data_type == Ans.ACC_BOARD_FLAG:
        return AccBoardFlag(struct.unpack_from("<I", data)[0])
    return RawReply(desc.data_type, bytes(data))
