# ROS 2 type hashes (REP 2011, RIHS01): sha256 of a message type's description, as rosidl makes it.
from __future__ import annotations

import hashlib
import json
from functools import cache
from typing import Any

from daemon.messages.msgtypes import Field, get_type

PREFIX = "RIHS01_"
#: rosidl's FIELD_TYPE ids of the .msg primitives (a .msg char is an IDL uint8, byte an octet)
_TYPE_IDS = {
    "int8": 2, "uint8": 3, "char": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7,
    "int64": 8, "uint64": 9, "float32": 10, "float64": 11, "bool": 15, "byte": 16,
    "string": 17, "wstring": 18,
}
NESTED = 1
#: added to an element's id: a fixed-size array, an unbounded sequence
ARRAY, SEQUENCE = 48, 144
#: rosidl's member of a message without fields
EMPTY_MEMBER = Field("structure_needs_at_least_one_member", "uint8")


def _field(field: Field) -> dict[str, Any]:
    nested = field.base not in _TYPE_IDS
    type_id = NESTED if nested else _TYPE_IDS[field.base]
    if field.is_array:
        type_id += ARRAY if field.length is not None else SEQUENCE
    return {"name": field.name,
            "type": {"type_id": type_id, "capacity": field.length or 0, "string_capacity": 0,
                     "nested_type_name": field.base if nested else ""}}


def _individual(name: str) -> dict[str, Any]:
    fields = get_type(name).fields or (EMPTY_MEMBER,)
    return {"type_name": name, "fields": [_field(f) for f in fields]}


def _references(name: str) -> list[str]:
    """Every type ``name`` refers to, directly or through others, sorted by name."""
    found: set[str] = set()
    queue = [name]
    while queue:
        for field in get_type(queue.pop()).fields:
            if field.base not in _TYPE_IDS and field.base not in found:
                found.add(field.base)
                queue.append(field.base)
    return sorted(found)


def type_description(name: str) -> dict[str, Any]:
    """The hashed part of ``type_description_interfaces/msg/TypeDescription`` for ``name``
    (``pkg/msg/Type``): its fields and those of every type it refers to, default values
    left out."""
    return {"type_description": _individual(name),
            "referenced_type_descriptions": [_individual(n) for n in _references(name)]}


@cache
def type_hash(name: str) -> str:
    """``RIHS01_<sha256 hex>`` of ``pkg/msg/Type``, equal to the hash rosidl generates."""
    text = json.dumps(type_description(name), ensure_ascii=True, allow_nan=False, indent=None,
                      separators=(", ", ": "), sort_keys=False)
    return PREFIX + hashlib.sha256(text.encode()).hexdigest()


def user_data(name: str) -> bytes:
    """The USER_DATA QoS of an endpoint of ``name``, as the ROS 2 middlewares write it."""
    return f"typehash={type_hash(name)};".encode()
