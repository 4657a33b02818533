# Strict checking of an outgoing message: every field of its type there, nothing else, by path.
from __future__ import annotations

import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from daemon.messages import cdr
from daemon.messages.msgtypes import BYTE_ARRAY_BASES, FLOAT_MAX, INT_RANGES, Field, get_type

# A converter's dict goes to JSON as it is (a missing field is simply absent there), but the
# CDR encoders (the flight recorder, rosbridge's cbor-raw, the ROS 2 face) need every field,
# and drop a key that is not one. check_fields finds both, and the scalars of the wrong kind
# that the encoders would coerce silently (a bool field given 1, a string field given None).


@dataclass
class FieldCheck:
    """What :func:`check_fields` found. ``unchecked``: sequences of messages that were empty
    everywhere in the message (``transforms[]``), so the fields of their elements were not
    looked at."""

    problems: list[str] = field(default_factory=list)
    unchecked: set[str] = field(default_factory=set)
    _seen: set[str] = field(default_factory=set, repr=False)
    #: (the problem's place with ``[]`` for indices, what) => [its first text, how many]
    _found: dict[tuple[str, str], list[Any]] = field(default_factory=dict, repr=False)

    @property
    def ok(self) -> bool:
        return not self.problems

    def _add(self, shape: str, what: str, path: str) -> None:
        """A problem at ``path``; the same one in other items of a sequence is counted."""
        found = self._found.setdefault((shape, what), [f"{path}{what}", 0])
        found[1] += 1

    def _finish(self) -> None:
        self.unchecked -= self._seen
        self.problems = [text if count == 1 else f"{text} (and in {count - 1} more items)"
                         for text, count in self._found.values()]


def check_fields(type_name: str, msg: Any) -> FieldCheck:
    """``msg`` (a converter's dict) compared with the definition of ``type_name``, recursively:
    each missing field, each key that is no field, and each scalar of the wrong kind is a
    problem naming its path (``header.stamp.nanosec: missing``)."""
    check = FieldCheck()
    _message(check, type_name, msg, "msg", "msg")
    check._finish()
    return check


def encode_strict(type_name: str, msg: Any) -> bytes:
    """:func:`cdr.encode` that first fails, naming every problem, when ``msg`` is not exactly
    its type (the plain encoder names only the first missing key and ignores extra ones)."""
    check = check_fields(type_name, msg)
    if not check.ok:
        raise cdr.CdrError(f"{type_name}: " + "; ".join(check.problems))
    return cdr.encode(type_name, msg)


def _message(check: FieldCheck, type_name: str, value: Any, path: str, shape: str) -> None:
    if not isinstance(value, Mapping):
        check._add(shape, f": expected a dict ({type_name}), got {type(value).__name__}",
                   path)
        return
    fields = get_type(type_name).fields
    names = {f.name for f in fields}
    for key in value:
        if key not in names:
            check._add(f"{shape}.{key}", f": not a field of {type_name}", f"{path}.{key}")
    for f in fields:
        if f.name not in value:
            check._add(f"{shape}.{f.name}", f": missing ({f.declared})", f"{path}.{f.name}")
        else:
            _field(check, f, value[f.name], f"{path}.{f.name}", f"{shape}.{f.name}")


def _field(check: FieldCheck, f: Field, value: Any, path: str, shape: str) -> None:
    if not f.is_array:
        if f.is_primitive:
            _scalar(check, f.base, value, path, shape)
        else:
            _message(check, f.base, value, path, shape)
        return
    if f.base in BYTE_ARRAY_BASES and isinstance(value, bytes | bytearray):
        items: Any = value
    elif isinstance(value, list | tuple | np.ndarray):
        items = value
    else:
        check._add(shape, f": expected an array of {f.base}, got {type(value).__name__}",
                   path)
        return
    if f.length is not None and len(items) != f.length:
        check._add(shape, f": expected exactly {f.length} items, got {len(items)}", path)
    if f.is_primitive:
        if f.base in ("string", "wstring"):
            for index, item in enumerate(items):
                _scalar(check, f.base, item, f"{path}[{index}]", f"{shape}[]")
        return  # numeric arrays: the encoder converts them as a whole and fails if it cannot
    (check._seen if len(items) else check.unchecked).add(f"{shape}[]")
    for index, item in enumerate(items):
        _message(check, f.base, item, f"{path}[{index}]", f"{shape}[]")


def _scalar(check: FieldCheck, base: str, value: Any, path: str, shape: str) -> None:
    if base in ("string", "wstring"):
        fits = isinstance(value, str)
    elif base == "bool":
        fits = isinstance(value, bool | np.bool_)
    elif base in INT_RANGES:
        fits = isinstance(value, numbers.Integral) and not isinstance(value, bool | np.bool_)
    elif base in FLOAT_MAX:
        fits = isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)
    else:
        fits = True
    if not fits:
        check._add(shape, f": expected {base}, got {type(value).__name__} {value!r:.40}",
                   path)
