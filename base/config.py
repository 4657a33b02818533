# The validated configuration and its typed, frozen per-section settings.
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

from base.options import Options, options_of

BUILTIN = "<built-in defaults>"

S = TypeVar("S", bound="SectionSettings")


class ConfigError(Exception):
    """One or more configuration problems; each names the file, section and key."""

    def __init__(self, problems: list[str]) -> None:
        super().__init__("\n".join(problems))
        self.problems = problems


def field_name(key: str) -> str:
    """A config key as a settings field: dots become underscores."""
    return key.replace(".", "_")


class OptionTable:
    """``SettingsClass.OPTIONS``: the option table generated from the class's fields
    (:func:`base.options.options_of`) on first use, then kept."""

    def __get__(self, instance: object, owner: type) -> Options:
        if "__dataclass_fields__" not in owner.__dict__:
            return {}  # @dataclass looking at the class it is making
        table: Options | None = owner.__dict__.get("_option_table")
        if table is None:
            table = options_of(owner)
            setattr(owner, "_option_table", table)  # noqa: B010 (a frozen dataclass's class)
        return table


@dataclass(frozen=True)
class SectionSettings:
    """Base of the typed settings of one config section: a frozen dataclass whose fields are
    the section's keys (dots as underscores), each declared once with
    :func:`base.options.option`; read once by :meth:`Config.get`.

    A subclass names its section (and any old names it still loads under, with a deprecation
    warning)::

        @dataclass(frozen=True)
        class HttpSettings(SectionSettings, section="http"):
            port: int = option(8085, "listen port", minval=1, maxval=65535)
            ...

    ``OPTIONS`` (key => :class:`~base.options.Option`, for the loader, ``arbiterd check``, the
    example config and the docs) is generated from the fields.
    """

    SECTION: ClassVar[str]
    #: old section names still read, with a deprecation warning: ``aliases=("record",)``
    ALIASES: ClassVar[tuple[str, ...]] = ()
    OPTIONS: ClassVar[OptionTable] = OptionTable()

    def __init_subclass__(cls, *, section: str = "", aliases: tuple[str, ...] = (),
                          **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if section:
            cls.SECTION = section
            cls.ALIASES = aliases

    @classmethod
    def from_values(cls: type[S], values: dict[str, Any]) -> S:
        return cls(**{field_name(key): value for key, value in values.items()})

    @classmethod
    def fields(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls)]


@dataclass
class Config:
    """Validated configuration: every section with every key, defaults filled in.

    Code reads a section once, typed: ``config.get(HttpSettings).port``. The raw section
    dicts (``config["http"]``) are what the loader, ``check`` and the example config print.
    """

    sections: dict[str, dict[str, Any]]
    source: str = BUILTIN
    sim: bool = True
    token: str = ""
    warnings: list[str] = field(default_factory=list)
    _typed: dict[type, Any] = field(default_factory=dict, repr=False, compare=False)

    def __getitem__(self, section: str) -> dict[str, Any]:
        return self.sections[section]

    def get(self, settings: type[S]) -> S:
        """The typed settings of a section (built once; :meth:`update` rebuilds them)."""
        cached = self._typed.get(settings)
        if cached is None:
            cached = self._typed[settings] = settings.from_values(
                self.sections[settings.SECTION])
        return cached

    def update(self, section: str, values: dict[str, Any]) -> None:
        """Change keys of a section (the simulator pointing the driver at its emulator)."""
        self.sections[section].update(values)
        self._typed.clear()

    def driver_options(self, name: str | None = None) -> dict[str, Any]:
        """The ``[driver.<name>]`` section (default: the configured driver type)."""
        return self.sections[f"driver.{name or self['driver']['type']}"]

    def as_dict(self) -> dict[str, Any]:
        return {name: dict(values) for name, values in self.sections.items()}
