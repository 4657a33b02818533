# ROS 2 CDR (little-endian XCDR1) decoding into message dicts, from the daemon's .msg texts.
from __future__ import annotations

import struct
from typing import Any

from daemon.messages.cdr import BYTE_BASES, ENCAPSULATION, HEADER_SIZE, PRIMITIVE_CODES, CdrError
from daemon.messages.msgtypes import Field, get_type

#: encapsulation kinds accepted: plain CDR, little-endian (ROS 2's own) and big-endian
LITTLE = ENCAPSULATION[:2]
BIG = b"\x00\x00"


def decode(type_name: str, data: bytes) -> dict[str, Any]:
    """One serialised message (encapsulation header included) as a dict shaped like the
    type; anything that does not fit (too short, a string without its terminator, a count
    past the end) is a :class:`CdrError` naming the field."""
    if len(data) < HEADER_SIZE or data[:2] not in (LITTLE, BIG):
        raise CdrError(f"{type_name}: not a plain CDR sample (header {data[:4].hex()})")
    reader = CdrReader(data, "<" if data[:2] == LITTLE else ">")
    return reader.message(type_name, "msg")


class CdrReader:
    """A cursor over one sample; alignment counts from the end of the encapsulation header."""

    def __init__(self, data: bytes, order: str) -> None:
        self.data = data
        self.order = order
        self.pos = HEADER_SIZE

    def align(self, size: int) -> None:
        self.pos += -(self.pos - HEADER_SIZE) % size

    def take(self, count: int, path: str) -> bytes:
        end = self.pos + count
        if count < 0 or end > len(self.data):
            raise CdrError(f"{path}: the sample ends before this field")
        chunk = self.data[self.pos:end]
        self.pos = end
        return chunk

    def scalar(self, base: str, path: str) -> Any:
        code = PRIMITIVE_CODES[base][0]
        size = struct.calcsize(code)
        self.align(size)
        value = struct.unpack(self.order + code, self.take(size, path))[0]
        if base == "bool" and self.data[self.pos - 1] > 1:
            raise CdrError(f"{path}: a bool must be 0 or 1")
        return value

    def count(self, path: str) -> int:
        n = int(self.scalar("uint32", path))
        if n > len(self.data) - self.pos:  # every element takes at least one byte
            raise CdrError(f"{path}: {n} elements cannot fit in the sample")
        return n

    def string(self, path: str) -> str:
        n = int(self.scalar("uint32", path))
        raw = self.take(n, path)
        if n == 0 or raw[-1] != 0:
            raise CdrError(f"{path}: a string must end with its NUL terminator")
        try:
            return raw[:-1].decode()
        except UnicodeDecodeError:
            raise CdrError(f"{path}: not UTF-8") from None

    def message(self, type_name: str, path: str) -> dict[str, Any]:
        fields = get_type(type_name).fields
        if not fields:
            self.take(1, path)  # an empty struct is one dummy byte
            return {}
        return {f.name: self.field(f, f"{path}.{f.name}") for f in fields}

    def field(self, f: Field, path: str) -> Any:
        if not f.is_array:
            return self.one(f.base, path)
        n = f.length if f.length is not None else self.count(path)
        if f.base in BYTE_BASES:
            return self.take(n, path)
        return [self.one(f.base, f"{path}[{i}]") for i in range(n)]

    def one(self, base: str, path: str) -> Any:
        if base in PRIMITIVE_CODES:
            return self.scalar(base, path)
        if base == "string":
            return self.string(path)
        if base == "wstring":
            raise CdrError(f"{path}: wstring is not supported")
        return self.message(base, path)
