# The motor driver contract: a small async base class with a template method.
from __future__ import annotations

import contextlib
import importlib
import math
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, ClassVar, NamedTuple, TypeVar

from base.options import Options, defaults, option, options_of
from drivers.registry import registered_name

S = TypeVar("S")


class DriverError(Exception):
    """Base of every driver error."""


class DriverClosed(DriverError):
    """A command reached a driver after ``close()``."""


class DriverFault(DriverError):
    """The hardware failed: a write error, a lost port, a lost peer, a missed heartbeat."""


class InvalidCommand(DriverError, ValueError):
    """A wheel speed that is not a finite number."""


class EncoderReading(NamedTuple):
    """Wheel positions in radians (forward positive) and the monotonic time they were read.
    (Immutable; a NamedTuple because one is made every tick: a frozen dataclass costs ~4x.)"""

    left_rad: float
    right_rad: float
    t_mono: float


class MotorDriver(ABC):
    """Base of every motor driver.

    The public methods live here and do the common work: validate and clamp the command to
    ``max_wheel_speed`` (rad/s), refuse after ``close()``, time each write, turn hardware
    exceptions into :class:`DriverFault`, and keep the health counters. A subclass implements
    the hardware part: ``_open``, ``_apply``, ``_close`` and optionally ``_read_encoders``,
    ``_health`` and ``_safe_stop``, and ``_emergency_zero`` for :meth:`emergency_stop`.

    A driver that notices a fault on its own (a missed heartbeat, a vanished peer) calls
    :meth:`report_fault`; the control loop polls :attr:`fault` every tick, stops the wheels and
    reconnects with back-off (``close()`` then ``open()`` on the same object).

    The ``[driver.<name>]`` options are read once, at construction, into ``self.settings``: an
    instance of ``SETTINGS``, a frozen dataclass whose fields declare the keys (``OPTIONS`` is
    generated from it).
    """

    #: Options of this driver's ``[driver.<name>]`` config section, generated from ``SETTINGS``.
    OPTIONS: ClassVar[Options] = {}
    #: The typed settings the options are read into: a frozen dataclass declaring one key per
    #: field with :func:`base.options.option`.
    SETTINGS: ClassVar[type[Any]]
    settings: Any

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "SETTINGS" in cls.__dict__:
            cls.OPTIONS = options_of(cls.SETTINGS)

    def __init__(self, options: Mapping[str, Any], *, max_wheel_speed: float) -> None:
        self.settings = read_settings(self.SETTINGS, self.OPTIONS, options, self.name())
        self.max_wheel_speed = max_wheel_speed
        self.is_open = False
        self.is_closed = False
        self.fault: str | None = None
        self.writes = 0
        self.write_errors = 0
        self.last_command: tuple[float, float] = (0.0, 0.0)
        self.last_write_mono: float | None = None
        self.last_write_duration_s = 0.0
        self.emergency_stops = 0
        self.emergency_failures = 0
        self.last_emergency_error = ""
        self.last_emergency_duration_s = 0.0
        self._emergency_count_lock = threading.Lock()

    async def open(self) -> None:
        """Connect to the hardware. May be called again after ``close()`` to reconnect."""
        try:
            await self._open()
        except DriverError:
            raise
        except Exception as exc:
            raise DriverFault(f"open failed: {exc}") from exc
        self.is_open, self.is_closed, self.fault = True, False, None
        self.last_command = (0.0, 0.0)

    def rest_hold_s(self) -> float:
        """How long a zero written to this hardware stands without being written again
        (the control loop re-writes it at rest at least this often); overridden by hardware
        that needs feeding (a deadman that would otherwise fire)."""
        return math.inf

    async def set_wheel_speeds(self, left_rad_s: float, right_rad_s: float) -> tuple[float, float]:
        """Command both wheels (rad/s, forward positive); returns the clamped pair written."""
        if self.is_closed or not self.is_open:
            raise DriverClosed("driver is closed" if self.is_closed else "driver is not open")
        limit = self.max_wheel_speed
        if type(left_rad_s) is float and type(right_rad_s) is float \
                and -limit <= left_rad_s <= limit and -limit <= right_rad_s <= limit:
            left, right = left_rad_s, right_rad_s  # the common case: nothing to clamp
        else:
            left, right = self.clamp(left_rad_s), self.clamp(right_rad_s)
        start = time.monotonic()
        try:
            await self._apply(left, right)
        except DriverError as exc:
            self._count_write_error(str(exc))
            raise
        except Exception as exc:
            self._count_write_error(f"write failed: {exc}")
            raise DriverFault(f"write failed: {exc}") from exc
        end = time.monotonic()
        self.writes += 1
        self.last_command = (left, right)
        self.last_write_mono = end
        self.last_write_duration_s = end - start
        return left, right

    def clamp(self, speed: float) -> float:
        """Refuse a non-finite speed; clamp a finite one to ``±max_wheel_speed``."""
        limit = self.max_wheel_speed
        if type(speed) is float and speed - speed == 0.0:  # finite float: the common case
            return limit if speed > limit else -limit if speed < -limit else speed
        if isinstance(speed, bool) or not isinstance(speed, int | float):
            raise InvalidCommand(f"wheel speed must be a number, got {type(speed).__name__}")
        if not math.isfinite(speed):
            raise InvalidCommand(f"wheel speed must be finite, got {speed}")
        return max(-self.max_wheel_speed, min(self.max_wheel_speed, float(speed)))

    def read_encoders(self) -> EncoderReading | None:
        """Wheel positions, or ``None`` when this hardware has no encoders (open loop). Never
        waits: a driver keeps its latest reading in memory (a background poll, the encoder
        callbacks, the controller's own messages), so the control tick never blocks on I/O."""
        if not self.is_open:
            return None
        try:
            return self._read_encoders()
        except DriverError:
            raise
        except Exception as exc:
            raise DriverFault(f"encoder read failed: {exc}") from exc

    async def stop(self) -> None:
        """Command zero speed on both wheels."""
        await self.set_wheel_speeds(0.0, 0.0)

    async def close(self) -> None:
        """Stop the wheels where still possible and release the hardware. Idempotent."""
        if self.is_closed:
            return
        if self.is_open and self.fault is None:
            with contextlib.suppress(DriverError):
                await self.stop()
        self.is_open, self.is_closed = False, True
        await self._close()

    async def safe_stop(self) -> None:
        """Zero the motors from a fresh process (``arbiterd safe-stop``), then close."""
        await self.open()
        try:
            await self._safe_stop()
        finally:
            await self.close()

    async def try_zero(self) -> bool:
        """Best effort to zero the wheels after a fault; True when the hardware took it."""
        try:
            await self._apply(0.0, 0.0)
        except Exception:
            return False
        self.last_command = (0.0, 0.0)
        return True

    def emergency_stop(self) -> bool:
        """Zero the wheels now, from any thread, without the event loop; True when it went out.

        The stall supervisor's path: synchronous, bounded in time (each driver uses its own
        lock or connection, with timeouts), never raises, counted in :meth:`health`. Before
        ``open()`` and after ``close()`` it does nothing and returns False.
        """
        if self.is_closed or not self.is_open:
            return False
        start = time.monotonic()
        try:
            ok = bool(self._emergency_zero())
            error = "" if ok else "the hardware could not be reached"
        except Exception as exc:  # the supervisor thread must never die of a driver error
            ok, error = False, f"{type(exc).__name__}: {exc}"
        with self._emergency_count_lock:
            self.emergency_stops += 1
            self.last_emergency_duration_s = time.monotonic() - start
            if not ok:
                self.emergency_failures += 1
                self.last_emergency_error = error
        if ok:
            self.last_command = (0.0, 0.0)
        return ok

    def report_fault(self, reason: str) -> None:
        """Mark the driver faulted; the control loop stops and reconnects it."""
        if self.fault is None:
            self.fault = reason

    def health(self) -> dict[str, Any]:
        """State and counters for ``/api/health``."""
        status = "error" if self.fault else ("ok" if self.is_open else "error")
        return {
            "status": status,
            "driver": self.name(),
            "open": self.is_open,
            "fault": self.fault,
            "writes": self.writes,
            "write_errors": self.write_errors,
            "last_command_rad_s": list(self.last_command),
            "last_write_ms": round(self.last_write_duration_s * 1e3, 4),
            "emergency_stops": self.emergency_stops,
            "emergency_failures": self.emergency_failures,
            "last_emergency_ms": round(self.last_emergency_duration_s * 1e3, 3),
            "last_emergency_error": self.last_emergency_error,
            **self._health(),
        }

    @classmethod
    def name(cls) -> str:
        """The name this class (or the registered class it extends) has in ``DRIVERS``."""
        for klass in cls.__mro__:
            name = registered_name(klass.__module__, klass.__name__)
            if name is not None:
                return name
        return cls.__name__

    def _count_write_error(self, reason: str) -> None:
        self.write_errors += 1
        self.report_fault(reason)

    # -- the hardware part ------------------------------------------------------------------

    @abstractmethod
    async def _open(self) -> None:
        """Connect and leave the motors stopped."""

    @abstractmethod
    async def _apply(self, left_rad_s: float, right_rad_s: float) -> None:
        """Write already validated and clamped wheel speeds."""

    @abstractmethod
    async def _close(self) -> None:
        """Release the hardware; the wheels were already stopped if that was possible."""

    @abstractmethod
    def _emergency_zero(self) -> bool:
        """Command zero on both wheels from a thread that is not the event loop's.

        Use the driver's own lock or connection (never the event loop), bound every wait, and
        leave nothing behind that would re-send an older speed (keep-alives). True when the
        zero command went out.
        """

    def _read_encoders(self) -> EncoderReading | None:
        return None

    async def _safe_stop(self) -> None:
        await self.stop()

    def _health(self) -> dict[str, Any]:
        return {}


SIDES = ("left", "right")


# The four direction keys every hardware driver spells the same way: a side's motor command
# and its encoder reading are flipped independently (a mirrored mount: both). A driver's
# settings declare ``left_motor_inverted: bool = motor_inverted("left")`` and so on.
def motor_inverted(side: str, default: bool = False) -> Any:
    return option(default, f"flip the {side} motor's command (it turns the wheel backward for "
                  "a forward command)")


def encoder_inverted(side: str, default: bool = False) -> Any:
    return option(default, f"flip the {side} encoder's reading (it counts down when the wheel "
                  "turns forward)")


def inversion_signs(settings: Any, side: str) -> tuple[float, float]:
    """(motor sign, encoder sign) of one side from the typed settings: -1.0 where inverted."""
    motor = getattr(settings, f"{side}_motor_inverted")
    encoder = getattr(settings, f"{side}_encoder_inverted")
    return (-1.0 if motor else 1.0), (-1.0 if encoder else 1.0)


def _renamed() -> dict[str, str]:
    renamed = {}
    for side in SIDES:
        both = f"{side}_motor_inverted = true and {side}_encoder_inverted = true"
        renamed[f"invert_{side}"] = both
        renamed[f"{side}_inverted"] = both
        renamed[f"{side}_invert"] = f"{side}_motor_inverted"
        renamed[f"{side}_encoder_invert"] = f"{side}_encoder_inverted"
    return renamed


#: Old driver keys (before one spelling across drivers) => what replaces them.
RENAMED_KEYS: dict[str, str] = _renamed()


def renamed_hint(key: str) -> str | None:
    """'renamed: did you mean ...' for an old driver key, else ``None``."""
    new = RENAMED_KEYS.get(key)
    return f"renamed; did you mean {new}?" if new else None


def read_settings(settings: type[S], declared: Options, given: Mapping[str, Any],
                  name: str, *, section: str | None = None) -> S:
    """The defaults plus ``given``, each key checked against ``declared``, as ``settings``
    (a dataclass with one field per declared key). A driver or device may be built without the
    config loader, so an unknown key or a bad value is a ``ValueError`` naming its section
    (``[driver.<name>]`` unless ``section`` says otherwise)."""
    where = section or f"driver.{name}"
    unknown = sorted(set(given) - set(declared))
    for key in unknown:
        hint = renamed_hint(key)
        if hint:
            raise ValueError(f"[{where}] {key}: {hint}")
    if unknown:
        raise ValueError(f"[{where}] unknown option(s): {', '.join(unknown)}; "
                         f"valid: {', '.join(sorted(declared))}")
    values = defaults(declared)
    for key, value in given.items():
        normalised, error = declared[key].validate(value)
        if error:
            raise ValueError(f"[{where}] {key}: {error}")
        values[key] = normalised
    return settings(**values)


def registered_class(table: Mapping[str, tuple[str, str]], name: str, kind: str,
                     unknown: type[Exception], broken: type[Exception]) -> Any:
    """The class registered as ``name`` in a plugin table (``name: (module, class)``), its
    module imported only now. An unknown name is ``unknown`` listing the valid ones; a module
    that cannot be imported is ``broken`` saying why."""
    try:
        module_name, class_name = table[name]
    except KeyError:
        raise unknown(f"unknown {kind} {name!r}; valid {kind}s: "
                      f"{', '.join(sorted(table))}") from None
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise broken(f"{kind} {name!r} cannot be imported: {exc}") from None
    return getattr(module, class_name)
