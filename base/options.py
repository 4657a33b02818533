# Typed, range-checked option declarations that every config section is built from.
from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

OptionKind = type | tuple[type, ...]


@dataclass(frozen=True)
class Option:
    """One config key: its type, default, bounds and a one-line description.

    ``kind`` is ``bool``, ``int``, ``float``, ``str`` or ``list``; ``float`` also accepts an
    integer. ``item`` is the element type of a list. ``choices`` restricts strings. ``minval``
    and ``maxval`` are inclusive, ``above``/``below`` exclusive. ``check`` is an extra validator
    returning an error text or ``None``.
    """

    kind: type
    default: Any
    doc: str
    minval: float | None = None
    maxval: float | None = None
    above: float | None = None
    below: float | None = None
    choices: Sequence[str] | None = None
    item: type | None = None
    length: int | None = None
    check: Callable[[Any], str | None] | None = field(default=None, compare=False)

    def validate(self, value: Any) -> tuple[Any, str | None]:
        """Return the normalised value and an error text (``None`` when valid)."""
        value, err = _coerce(self.kind, value)
        if err:
            return value, err
        if self.kind is list:
            return self._validate_list(value)
        return value, self._validate_scalar(value)

    def _validate_list(self, value: list[Any]) -> tuple[Any, str | None]:
        if self.length is not None and len(value) != self.length:
            return value, f"expected a list of {self.length} items, got {len(value)}"
        out = []
        for i, element in enumerate(value):
            element, err = _coerce(self.item or str, element)
            if err:
                return value, f"item {i}: {err}"
            err = self._validate_scalar(element)
            if err:
                return value, f"item {i}: {err}"
            out.append(element)
        return out, self._run_check(out)

    def _validate_scalar(self, value: Any) -> str | None:
        if isinstance(value, float) and not math.isfinite(value):
            return f"must be a finite number, got {value}"
        if self.choices is not None and value not in self.choices:
            return f"must be one of {', '.join(map(repr, self.choices))}, got {value!r}"
        if isinstance(value, int | float) and not isinstance(value, bool):
            err = _range_error(value, self.minval, self.maxval, self.above, self.below)
            if err:
                return err
        return self._run_check(value)

    def _run_check(self, value: Any) -> str | None:
        return self.check(value) if self.check else None


def _coerce(kind: type, value: Any) -> tuple[Any, str | None]:
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value), None
    if kind is int and isinstance(value, bool):
        return value, f"expected an integer, got {value!r}"
    if not isinstance(value, kind):
        return value, f"expected {_kind_name(kind)}, got {type(value).__name__} {value!r}"
    return value, None


def _kind_name(kind: type) -> str:
    names = {bool: "true/false", int: "an integer", float: "a number", str: "a string",
             list: "a list"}
    return names.get(kind, kind.__name__)


def _range_error(value: float, minval: float | None, maxval: float | None,
                 above: float | None, below: float | None) -> str | None:
    if minval is not None and value < minval:
        return f"must be >= {minval}, got {value}"
    if maxval is not None and value > maxval:
        return f"must be <= {maxval}, got {value}"
    if above is not None and value <= above:
        return f"must be > {above}, got {value}"
    if below is not None and value >= below:
        return f"must be < {below}, got {value}"
    return None


Options = Mapping[str, Option]


def defaults(options: Options) -> dict[str, Any]:
    """The default values of a set of options."""
    return {key: opt.default for key, opt in options.items()}


#: the metadata key under which a settings field carries its declaration (see :func:`option`)
DECLARATION = "arbiterd.option"


def option(default: Any, doc: str, *, key: str | None = None, minval: float | None = None,
           maxval: float | None = None, above: float | None = None, below: float | None = None,
           choices: Sequence[str] | None = None, item: type | None = None,
           length: int | None = None, check: Callable[[Any], str | None] | None = None) -> Any:
    """Declare one config key as a field of a settings dataclass: its default, doc and bounds
    (the :class:`Option` arguments). The kind (and a list's item type) comes from the field's
    annotation, the key from its name unless ``key`` says otherwise (``key="linear.x.max_velocity"``
    for the field ``linear_x_max_velocity``). :func:`options_of` makes the option table::

        @dataclass(frozen=True)
        class HttpSettings(SectionSettings, section="http"):
            port: int = option(8085, "listen port", minval=1, maxval=65535)
    """
    declared = {"default": default, "doc": doc, "key": key, "minval": minval, "maxval": maxval,
                "above": above, "below": below, "choices": choices, "item": item,
                "length": length, "check": check}
    metadata = {DECLARATION: declared}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=metadata)
    return field(default=default, metadata=metadata)


def shared_option(default: Any, doc: str, **kwargs: Any) -> dict[str, Any]:
    """The :func:`option` arguments of a key several settings classes have (the keys two
    drivers share), written once: each class declares ``min_duty: float = option(**MIN_DUTY)``."""
    return {"default": default, "doc": doc, **kwargs}


def options_of(settings: type) -> dict[str, Option]:
    """The option table of a settings dataclass: one :class:`Option` per field, in field
    order, each declared by :func:`option`. A field declared otherwise, a key that does not
    match its field's name (dots as underscores) or a default of the wrong kind or out of its
    own bounds is a ``TypeError`` naming the class and field."""
    table: dict[str, Option] = {}
    for f in dataclasses.fields(settings):
        where = f"{settings.__qualname__}.{f.name}"
        declared = f.metadata.get(DECLARATION)
        if declared is None:
            raise TypeError(f"{where}: declare the field with option(default, doc, ...)")
        declared = dict(declared)
        key = declared.pop("key") or f.name
        if key.replace(".", "_") != f.name:
            raise TypeError(f"{where}: key {key!r} does not match the field's name")
        kind, item = kind_of(f.type, where)
        declared["item"] = declared["item"] or item
        table[key] = Option(kind, **declared)
        # the kind and bounds (a check may refuse what only the default may be, e.g. [])
        error = dataclasses.replace(table[key], check=None).validate(table[key].default)[1]
        if error:
            raise TypeError(f"{where}: default {table[key].default!r}: {error}")
    return table


_KINDS: dict[str, type] = {"bool": bool, "int": int, "float": float, "str": str, "list": list}


def kind_of(annotation: Any, where: str = "") -> tuple[type, type | None]:
    """(kind, list item type) of a field annotation: ``float`` => (float, None),
    ``list[int]`` => (list, int), ``list[list[Any]]`` => (list, list). Annotations are text
    under ``from __future__ import annotations``; a type works too."""
    text = annotation if isinstance(annotation, str) else _annotation_text(annotation)
    text = text.replace(" ", "")
    if text in _KINDS:
        return _KINDS[text], None
    inner = re.fullmatch(r"list\[(.+)\]", text)
    if inner:
        return list, _KINDS.get(inner.group(1).split("[", 1)[0])
    raise TypeError(f"{where}: a config key is bool, int, float, str or list[...], "
                    f"not {text}")


def _annotation_text(annotation: Any) -> str:
    return annotation.__name__ if isinstance(annotation, type) else str(annotation)
