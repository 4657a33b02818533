# L298N driver through gpiozero: a Motor per side, pin factory from config, RotaryEncoder odometry.
from __future__ import annotations

import contextlib
import math
import os
import tempfile
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from base.options import option
from drivers.base import (
    DriverFault,
    EncoderReading,
    MotorDriver,
    encoder_inverted,
    motor_inverted,
)
from drivers.pigpio_protocol import PI4B_REVISION
from drivers.pigpio_pwm import (
    DEADBAND,
    LEFT_ENCODER_A,
    LEFT_ENCODER_B,
    MAX_WHEEL_SPEED,
    MIN_DUTY,
    RIGHT_ENCODER_A,
    RIGHT_ENCODER_B,
    BridgeSettings,
    SerialExecutor,
    check_pins,
)
from drivers.pigpiod_client import drop_pigpio, probe_tcp
from drivers.pigpiod_watch import (
    LINK_TIMEOUT,
    LINK_WATCH_INTERVAL,
    Call,
    PigpiodWatch,
    describe_io_error,
)

T = TypeVar("T")
PIN_FACTORIES = ("lgpio", "rpigpio", "pigpio", "native", "mock")

_mock_factory: Any = None


def mock_pin_factory() -> Any:
    """The process-wide gpiozero MockFactory (PWM-capable pins, a Pi 4B) behind ``mock``.

    Tests and the simulator read and drive its pins to see what the driver does.
    """
    global _mock_factory
    if _mock_factory is None:
        from gpiozero.pins.mock import MockFactory, MockPWMPin

        _mock_factory = MockFactory(revision=f"{PI4B_REVISION:x}", pin_class=MockPWMPin)
    return _mock_factory


def _pin(default: int, doc: str, *, optional: bool = False) -> Any:
    return option(default, doc, minval=-1 if optional else 0, maxval=27)


def build_pin_factory(settings: L298NSettings) -> Any:
    """The gpiozero pin factory the config names; DriverFault when it cannot work here."""
    kind = settings.pin_factory
    try:
        if kind == "mock":
            return mock_pin_factory()
        if kind == "pigpio":
            return _pigpio_factory(settings)
        if kind == "lgpio":
            # importing lgpio creates a notification FIFO in $LG_WD (default: the cwd)
            os.environ.setdefault("LG_WD", os.environ.get("RUNTIME_DIRECTORY",
                                                          tempfile.gettempdir()))
            from gpiozero.pins.lgpio import LGPIOFactory

            return LGPIOFactory()
        if kind == "rpigpio":
            from gpiozero.pins.rpigpio import RPiGPIOFactory

            return RPiGPIOFactory()
        from gpiozero.pins.native import NativeFactory

        return NativeFactory()
    except DriverFault:
        raise
    except Exception as exc:
        raise DriverFault(f"[driver.l298n] pin_factory = {kind!r} unavailable: "
                          f"{type(exc).__name__}: {exc}") from exc


def _pigpio_factory(settings: L298NSettings) -> Any:
    from gpiozero.pins.pigpio import PiGPIOFactory

    host, port, timeout = settings.pigpio_host, settings.pigpio_port, settings.timeout
    probe_tcp(host, port, timeout)
    factory = PiGPIOFactory(host=host, port=port)
    factory.connection.sl.s.settimeout(timeout)
    return factory


@dataclass(frozen=True)
class L298NSettings(BridgeSettings):
    """The ``[driver.l298n]`` section: its keys, each declared once (``OPTIONS`` is made from
    them)."""

    pin_factory: str = option("lgpio", "gpiozero pin factory", choices=PIN_FACTORIES)
    pigpio_host: str = option("localhost", "pigpiod host (pin_factory = 'pigpio')")
    pigpio_port: int = option(8888, "pigpiod port (pin_factory = 'pigpio')", minval=1,
                              maxval=65535)
    left_forward: int = _pin(17, "left IN1 GPIO (PWM, forward)")
    left_backward: int = _pin(18, "left IN2 GPIO (PWM, backward)")
    left_enable: int = _pin(-1, "left ENA GPIO held high (-1 = jumpered)", optional=True)
    right_forward: int = _pin(22, "right IN3 GPIO (PWM, forward)")
    right_backward: int = _pin(23, "right IN4 GPIO (PWM, backward)")
    right_enable: int = _pin(-1, "right ENB GPIO held high (-1 = jumpered)", optional=True)
    left_motor_inverted: bool = motor_inverted("left")
    right_motor_inverted: bool = motor_inverted("right")
    left_encoder_inverted: bool = encoder_inverted("left")
    right_encoder_inverted: bool = encoder_inverted("right")
    pwm_frequency: int = option(500, "PWM frequency, Hz", minval=10, maxval=20000)
    max_wheel_speed: float = option(**MAX_WHEEL_SPEED)
    min_duty: float = option(**MIN_DUTY)
    deadband: float = option(**DEADBAND)
    encoders: bool = option(False, "read quadrature encoders with gpiozero RotaryEncoder")
    left_encoder_a: int = option(**LEFT_ENCODER_A)
    left_encoder_b: int = option(**LEFT_ENCODER_B)
    right_encoder_a: int = option(**RIGHT_ENCODER_A)
    right_encoder_b: int = option(**RIGHT_ENCODER_B)
    encoder_counts_per_rev: int = option(360, "full quadrature cycles (RotaryEncoder steps) per "
                                         "wheel revolution", minval=1)
    encoder_bounce: float = option(0.0, "encoder debounce time, s (0 = off)", minval=0.0,
                                   maxval=0.3)
    timeout: float = option(**LINK_TIMEOUT)
    watch_interval: float = option(**LINK_WATCH_INTERVAL)


class L298NDriver(MotorDriver):
    """Two L298N channels as gpiozero ``Motor`` devices (IN1/IN2 PWM, optional EN held high).

    Speeds map open loop to duty (``max_wheel_speed`` at full duty, ``min_duty``,
    ``deadband``); optional quadrature encoders are gpiozero ``RotaryEncoder`` devices. With
    the ``pigpio`` pin factory every pin access is a pigpiod round trip, so those run on a
    worker thread and a lost pigpiod is a fault.
    """

    SETTINGS = L298NSettings
    settings: L298NSettings

    def __init__(self, options: Mapping[str, Any], *, max_wheel_speed: float) -> None:
        super().__init__(options, max_wheel_speed=max_wheel_speed)
        s = self.settings
        self.full_duty_speed = s.max_wheel_speed or max_wheel_speed
        keys = [f"{side}_{p}" for side in ("left", "right")
                for p in ("forward", "backward", "enable")]
        check_pins(s, keys + s.encoder_pin_keys(), self.name())
        self.remote = s.pin_factory == "pigpio"
        self._factory: Any = None
        self._motors: list[Any] = []
        self._encoders: list[Any] = []
        self._offsets = [0, 0]
        self._values: list[float | None] = [None, None]
        self._write_lock = threading.Lock()  # motor writes: loop or worker, and emergency_stop()
        self._io: SerialExecutor | None = None
        self._watch = PigpiodWatch(self, s.watch_interval, self._peer,
                                   lambda _pi, reason: self._lost(reason))
        self.connects = 0

    # -- lifecycle ----------------------------------------------------------------------------

    async def _open(self) -> None:
        if self.remote:
            self._io = SerialExecutor("l298n-pigpio")
        try:
            await self._call(self._build)
        except BaseException:
            if self._io is not None:
                self._io.shutdown()
                self._io = None
            raise
        if self.remote:
            self._watch.start("l298n-pigpio-watch")

    async def _call(self, fn: Callable[..., T], *args: Any) -> T:
        """Run pin I/O: inline for local factories, on the worker thread for pigpiod."""
        if self._io is None:
            return fn(*args)
        return await self._io.call(fn, *args)

    def _build(self) -> None:
        factory = build_pin_factory(self.settings)
        try:
            self._motors = [self._motor(factory, side) for side in ("left", "right")]
            if self.settings.encoders:
                self._encoders = [self._encoder(factory, side) for side in ("left", "right")]
        except Exception as exc:
            self._factory = factory
            self._release(peer_alive=True)
            raise DriverFault(f"[driver.l298n] pin setup failed: {type(exc).__name__}: "
                              f"{exc}") from exc
        self._factory, self._values = factory, [0.0, 0.0]
        self.connects += 1

    def _motor(self, factory: Any, side: str) -> Any:
        from gpiozero import Motor

        s = self.settings
        enable = getattr(s, f"{side}_enable")
        motor = Motor(getattr(s, f"{side}_forward"), getattr(s, f"{side}_backward"),
                      enable=enable if enable >= 0 else None, pwm=True, pin_factory=factory)
        try:
            motor.forward_device.frequency = s.pwm_frequency
            motor.backward_device.frequency = s.pwm_frequency
            motor.stop()
        except Exception:
            motor.close()
            raise
        return motor

    def _encoder(self, factory: Any, side: str) -> Any:
        from gpiozero import RotaryEncoder

        pins = self.settings.encoder_pins(side)
        assert pins is not None  # built only with encoders on
        return RotaryEncoder(*pins, max_steps=0,
                             bounce_time=self.settings.encoder_bounce or None,
                             pin_factory=factory)

    async def _close(self) -> None:
        await self._watch.stop()
        await self._call(self._release, self.fault is None)
        if self._io is not None:
            self._io.shutdown()
            self._io = None

    def _release(self, peer_alive: bool) -> None:
        factory, self._factory = self._factory, None
        connection = getattr(factory, "_connection", None) if self.remote else None
        if connection is not None and not peer_alive:
            # gpiozero would talk to the dead pigpiod while closing pins; cut it loose first
            drop_pigpio(connection, peer_alive=False)
        for index, encoder in enumerate(self._encoders):
            with contextlib.suppress(Exception):
                self._offsets[index] += encoder.steps
        for device in [*self._encoders, *self._motors]:
            with contextlib.suppress(Exception):
                device.close()
        self._encoders, self._motors, self._values = [], [], [None, None]
        if factory is not None and self.settings.pin_factory != "mock":
            with contextlib.suppress(Exception):
                factory.close()
        if connection is not None:
            drop_pigpio(connection, peer_alive=False)  # idempotent; forgets its atexit hook

    # -- commands -----------------------------------------------------------------------------

    async def _apply(self, left_rad_s: float, right_rad_s: float) -> None:
        s = self.settings
        values = []
        for invert, speed in ((s.left_motor_inverted, left_rad_s),
                              (s.right_motor_inverted, right_rad_s)):
            duty = s.duty(speed, self.full_duty_speed)
            values.append(-duty if invert else duty)
        if not self._motors:
            raise DriverFault("l298n: motors are not set up")
        await self._call(self._write_locked, values)

    def _write(self, values: list[float]) -> None:
        try:
            for index, value in enumerate(values):
                if self._values[index] != value:
                    self._motors[index].value = value
                    self._values[index] = value
        except Exception as exc:
            self._values = [None, None]
            if self.remote:
                self._lost(f"write failed: {describe_io_error(exc)}")
                raise DriverFault(self.fault or "pigpiod lost") from exc
            raise DriverFault(f"l298n: GPIO write failed: {type(exc).__name__}: {exc}") from exc

    def _lost(self, reason: str) -> None:
        self.report_fault(f"pigpiod at {self._where()} lost: {reason}")
        factory = self._factory
        if factory is not None and factory._connection is not None:
            drop_pigpio(factory._connection, peer_alive=False)

    def _peer(self) -> tuple[Call, Any] | None:
        """What the keep-alive asks: the worker thread and gpiozero's pigpio client."""
        factory, io = self._factory, self._io
        if factory is None or io is None:
            return None
        return io.call, factory._connection

    # -- encoders and health ------------------------------------------------------------------

    def _read_encoders(self) -> EncoderReading | None:
        if not self.settings.encoders:
            return None
        left, right = (self._position(i, side) for i, side in enumerate(("left", "right")))
        return EncoderReading(left, right, time.monotonic())

    def _position(self, index: int, side: str) -> float:
        steps = self._offsets[index]
        if self._encoders:
            steps += self._encoders[index].steps
        sign = -1.0 if getattr(self.settings, f"{side}_encoder_inverted") else 1.0
        return sign * steps / self.settings.encoder_counts_per_rev * 2.0 * math.pi

    def _where(self) -> str:
        return f"{self.settings.pigpio_host}:{self.settings.pigpio_port}"

    def _health(self) -> dict[str, Any]:
        extra: dict[str, Any] = {"pin_factory": self.settings.pin_factory,
                                 "connects": self.connects, "duty": list(self._values)}
        if self.remote:
            extra["pigpiod"] = self._where()
        return extra

    # -- emergency path (any thread) -----------------------------------------------------------

    def _write_locked(self, values: list[float]) -> None:
        with self._write_lock:
            self._write(values)

    def _emergency_zero(self) -> bool:
        """gpiozero's ``Motor.stop()`` on both sides, under the write lock.

        gpiozero does not lock a Motor (a speed change is two pin writes), so the driver's own
        lock keeps these from interleaving with the event loop's or the worker thread's; with
        the pigpio pin factory each pin write waits at most ``timeout`` for pigpiod.
        """
        if not self._write_lock.acquire(timeout=self.settings.timeout):
            return False
        try:
            motors = list(self._motors)
            if not motors:
                return False
            self._values = [None, None]  # whatever happens next, the next write sends both
            for motor in motors:
                motor.stop()
            self._values = [0.0, 0.0]
            return True
        finally:
            self._write_lock.release()
