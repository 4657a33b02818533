# Hardware other than the wheel pair: actuators with named joints and sensors with named readings.
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from base.options import Options, options_of
from drivers.base import DriverError, read_settings, registered_class
from drivers.device_registry import DEVICES


class DeviceError(DriverError):
    """A device refused a command or its hardware failed; the message says which and why."""


@dataclass(frozen=True)
class Joint:
    """One named interface of an actuator and its limits (rad for revolute joints, m for
    prismatic ones)."""

    name: str
    lower: float
    upper: float

    def clamp(self, value: float) -> float:
        return min(max(value, self.lower), self.upper)


class Device(ABC):
    """Base of every device (ros2_control's hardware kinds: an :class:`Actuator` or a
    :class:`Sensor`). Template methods: the public ``open``/``close``/``health`` live here and
    keep the common state; a subclass implements ``_open``, ``_close`` and optionally
    ``_health``. Options are read once, at construction, into ``self.settings`` (``SETTINGS``,
    a frozen dataclass declaring one key per field with ``option()``; ``OPTIONS`` is made from
    it); a bad one is a ``ValueError`` naming ``[section] key``.
    """

    KIND: ClassVar[str]
    #: the device's keys, generated from ``SETTINGS`` (each field declared with ``option()``)
    OPTIONS: ClassVar[Options] = {}
    SETTINGS: ClassVar[type[Any]]
    settings: Any

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "SETTINGS" in cls.__dict__:
            cls.OPTIONS = options_of(cls.SETTINGS)

    def __init__(self, options: Mapping[str, Any], *, section: str) -> None:
        self.section = section
        self.settings = read_settings(self.SETTINGS, self.OPTIONS, options, section,
                                      section=section)
        self.is_open = False
        self.fault: str | None = None
        self._closed = False

    async def open(self) -> None:
        if self._closed:
            raise DeviceError(f"[{self.section}] device is closed")
        await self._open()
        self.is_open, self.fault = True, None

    async def close(self) -> None:
        """Release the hardware (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self.is_open:
            self.is_open = False
            await self._close()

    def health(self) -> dict[str, Any]:
        status = "error" if self.fault or not self.is_open else "ok"
        return {"status": status, "kind": self.KIND, "open": self.is_open,
                "fault": self.fault, **self._health()}

    @abstractmethod
    async def _open(self) -> None: ...

    @abstractmethod
    async def _close(self) -> None: ...

    def _health(self) -> dict[str, Any]:
        return {}


class Actuator(Device):
    """A device that takes position targets for named joints (servos, a gripper). The base
    refuses unknown joints and non-finite values, clamps to each joint's limits and remembers
    the last targets; ``_write`` sends already-checked targets to the hardware."""

    KIND = "actuator"

    def __init__(self, options: Mapping[str, Any], *, section: str) -> None:
        super().__init__(options, section=section)
        self.targets: dict[str, float] = {}

    @abstractmethod
    def joints(self) -> tuple[Joint, ...]: ...

    async def write(self, targets: Mapping[str, float]) -> dict[str, float]:
        """Send position targets (a subset of the joints); returns them as clamped."""
        if not self.is_open:
            raise DeviceError(f"[{self.section}] device is not open")
        clamped = self.check(targets)
        try:
            await self._write(clamped)
        except DeviceError as exc:
            self.fault = str(exc)
            raise
        self.targets.update(clamped)
        return clamped

    def check(self, targets: Mapping[str, float]) -> dict[str, float]:
        by_name = {joint.name: joint for joint in self.joints()}
        out: dict[str, float] = {}
        for name, value in targets.items():
            joint = by_name.get(name)
            if joint is None:
                raise DeviceError(f"[{self.section}] unknown joint {name!r}; joints: "
                                  f"{', '.join(by_name)}")
            if isinstance(value, bool) or not isinstance(value, int | float) \
                    or not math.isfinite(value):
                raise DeviceError(f"[{self.section}] joint {name}: expected a finite number, "
                                  f"got {value!r}")
            out[name] = joint.clamp(float(value))
        return out

    async def relax(self) -> None:
        """Stop holding position where the hardware can (servo pulses off)."""
        if self.is_open:
            await self._relax()

    @abstractmethod
    async def _write(self, targets: dict[str, float]) -> None: ...

    async def _relax(self) -> None:
        return None

    def _health(self) -> dict[str, Any]:
        return {"joints": [joint.name for joint in self.joints()], "targets": dict(self.targets)}


class Sensor(Device):
    """A device that is read: named readings (a range, a voltage)."""

    KIND = "sensor"

    @abstractmethod
    def readings(self) -> tuple[str, ...]: ...

    async def read(self) -> dict[str, float]:
        if not self.is_open:
            raise DeviceError(f"[{self.section}] device is not open")
        return await self._read()

    async def probe(self) -> dict[str, float]:
        """Open, read once, close (``arbiterd check``); a DeviceError says what is wrong."""
        try:
            await self.open()
            return await self.read()
        finally:
            await self.close()

    @abstractmethod
    async def _read(self) -> dict[str, float]: ...


def device_class(name: str) -> type[Device]:
    """Import and return the class registered as ``name``."""
    cls: type[Device] = registered_class(DEVICES, name, "device", DeviceError, DeviceError)
    return cls


def create_device(name: str, options: Mapping[str, Any], *, section: str) -> Device:
    """Build (not open) the device registered as ``name`` from the keys of ``options`` it
    declares (a component's section may hold keys of its own beside them)."""
    cls = device_class(name)
    return cls({k: v for k, v in options.items() if k in cls.OPTIONS}, section=section)
