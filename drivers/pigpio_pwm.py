# pigpio driver: L298N bridges driven through pigpiod (hardware or DMA PWM), encoder callbacks.
from __future__ import annotations

import asyncio
import contextlib
import math
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, TypeVar

from base.options import option, shared_option
from drivers.base import (
    DriverFault,
    EncoderReading,
    MotorDriver,
    encoder_inverted,
    motor_inverted,
)
from drivers.pigpio_deadman import Deadman
from drivers.pigpio_protocol import (
    EITHER_EDGE,
    HARDWARE_DUTY_FULL,
    HARDWARE_PWM_CHANNEL,
    MODE_INPUT,
    MODE_OUTPUT,
    PI_TIMEOUT_LEVEL,
    PUD_UP,
)
from drivers.pigpiod_client import connect_pigpio, drop_pigpio
from drivers.pigpiod_watch import (
    LINK_TIMEOUT,
    LINK_WATCH_INTERVAL,
    Call,
    PigpiodWatch,
    describe_io_error,
)
from drivers.quadrature import QuadratureDecoder

T = TypeVar("T")


def _gpio(default: int, doc: str) -> Any:
    return option(default, doc, minval=0, maxval=27)


# The keys the pigpio and l298n sections share, each declared once here; each driver's settings
# declare ``min_duty: float = option(**MIN_DUTY)`` and so on, in the order of their section.
#: the open-loop speed -> duty map
MAX_WHEEL_SPEED = shared_option(0.0, "wheel speed at full duty, rad/s (0 = the robot's maximum "
                                "wheel speed)", minval=0.0)
MIN_DUTY = shared_option(0.0, "smallest duty that turns the wheel (0..1)", minval=0.0, below=1.0)
DEADBAND = shared_option(0.0, "speeds at or below this, rad/s, stop the wheel", minval=0.0)
#: quadrature encoder wiring
LEFT_ENCODER_A = shared_option(5, "left encoder channel A GPIO", minval=0, maxval=27)
LEFT_ENCODER_B = shared_option(6, "left encoder channel B GPIO", minval=0, maxval=27)
RIGHT_ENCODER_A = shared_option(20, "right encoder channel A GPIO", minval=0, maxval=27)
RIGHT_ENCODER_B = shared_option(21, "right encoder channel B GPIO", minval=0, maxval=27)


# -- pure helpers (shared with the l298n driver) --------------------------------------------------


def speed_to_duty(speed: float, full_speed: float, min_duty: float, deadband: float) -> float:
    """Open-loop map of a wheel speed (rad/s) to a signed duty in -1..1.

    Speeds within ``deadband`` stop the wheel; any other speed maps linearly into
    ``min_duty..1`` so that a small command still overcomes the motor's static friction.
    """
    if speed == 0.0 or abs(speed) <= deadband:
        return 0.0
    fraction = min(1.0, abs(speed) / full_speed)
    return math.copysign(min_duty + (1.0 - min_duty) * fraction, speed)


@dataclass(frozen=True)
class Side:
    """One wheel's wiring as the pigpio driver uses it."""

    name: str
    pwm: int
    in1: int
    in2: int
    invert: bool
    encoder: tuple[int, int] | None
    encoder_invert: bool


class BridgeSettings:
    """What the pigpio and l298n settings share: bridges, duty map, encoders, pigpiod (each
    declares these keys among its own, in its section's order; the shared ones' options are
    declared once, above)."""

    left_motor_inverted: bool
    right_motor_inverted: bool
    left_encoder_inverted: bool
    right_encoder_inverted: bool
    pwm_frequency: int
    max_wheel_speed: float
    min_duty: float
    deadband: float
    encoders: bool
    left_encoder_a: int
    left_encoder_b: int
    right_encoder_a: int
    right_encoder_b: int
    encoder_counts_per_rev: int
    timeout: float
    watch_interval: float

    def duty(self, speed: float, full_speed: float) -> float:
        """The open-loop duty map (see :func:`speed_to_duty`) with this section's keys."""
        return speed_to_duty(speed, full_speed, self.min_duty, self.deadband)

    def encoder_pin_keys(self) -> list[str]:
        """The encoder GPIO keys in use (none with ``encoders`` off)."""
        if not self.encoders:
            return []
        return [f"{side}_encoder_{ch}" for side in ("left", "right") for ch in "ab"]

    def encoder_pins(self, side: str) -> tuple[int, int] | None:
        """(A, B) of one side's encoder, or ``None`` with ``encoders`` off."""
        if not self.encoders:
            return None
        return getattr(self, f"{side}_encoder_a"), getattr(self, f"{side}_encoder_b")


@dataclass(frozen=True)
class PigpioSettings(BridgeSettings):
    """The ``[driver.pigpio]`` section: its keys, each declared once (``OPTIONS`` is made from
    them)."""

    host: str = option("localhost", "host running pigpiod")
    port: int = option(8888, "pigpiod TCP port", minval=1, maxval=65535)
    left_pwm: int = _gpio(12, "left EN (PWM) GPIO; 12/13/18/19 get hardware PWM")
    left_in1: int = _gpio(23, "left IN1 GPIO (high = forward)")
    left_in2: int = _gpio(24, "left IN2 GPIO (high = backward)")
    right_pwm: int = _gpio(13, "right EN (PWM) GPIO; 12/13/18/19 get hardware PWM")
    right_in1: int = _gpio(27, "right IN1 GPIO (high = forward)")
    right_in2: int = _gpio(22, "right IN2 GPIO (high = backward)")
    left_motor_inverted: bool = motor_inverted("left")
    right_motor_inverted: bool = motor_inverted("right")
    left_encoder_inverted: bool = encoder_inverted("left")
    right_encoder_inverted: bool = encoder_inverted("right")
    hardware_pwm: bool = option(True, "use hardware PWM on GPIO 12/13/18/19")
    pwm_frequency: int = option(1000, "PWM frequency, Hz (DMA PWM rounds to pigpiod's nearest "
                                "allowed value)", minval=10, maxval=40000)
    pwm_range: int = option(1000, "DMA PWM duty steps", minval=25, maxval=40000)
    max_wheel_speed: float = option(**MAX_WHEEL_SPEED)
    min_duty: float = option(**MIN_DUTY)
    deadband: float = option(**DEADBAND)
    encoders: bool = option(False, "read quadrature encoders through pigpio callbacks")
    left_encoder_a: int = option(**LEFT_ENCODER_A)
    left_encoder_b: int = option(**LEFT_ENCODER_B)
    right_encoder_a: int = option(**RIGHT_ENCODER_A)
    right_encoder_b: int = option(**RIGHT_ENCODER_B)
    encoder_counts_per_rev: int = option(1440, "encoder edges (4 per quadrature cycle) per "
                                         "wheel revolution", minval=1)
    glitch_filter_us: int = option(100, "ignore encoder level changes shorter than this, us",
                                   minval=0, maxval=300000)
    timeout: float = option(**LINK_TIMEOUT)
    watch_interval: float = option(**LINK_WATCH_INTERVAL)
    deadman_s: float = option(0.5, "a script in pigpiod zeroes the motor pins when the driver has "
                              "not written for this long (a frozen or killed daemon), s; 0 = off",
                              minval=0.0, maxval=10.0)


# -- connection helpers (shared with the l298n driver) ---------------------------------------------


class SerialExecutor:
    """One worker thread for a driver's blocking socket calls, in order, off the event loop."""

    def __init__(self, name: str) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)

    async def call(self, fn: Callable[..., T], *args: Any) -> T:
        return await asyncio.get_running_loop().run_in_executor(self._pool, fn, *args)

    def shutdown(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


# -- the driver ------------------------------------------------------------------------------------


class PigpioDriver(MotorDriver):
    """Two L298N channels (EN = PWM, IN1/IN2 = direction) through pigpiod's socket interface.

    PWM pins 12/13/18/19 get hardware PWM (one per channel), other pins DMA PWM. With
    ``encoders`` on, quadrature edges arrive as pigpio callbacks and are decoded x4. A lost
    pigpiod (a failed write, or the keep-alive poll failing) is a fault; ``close()`` then
    ``open()`` reconnects, keeping the encoder totals.
    """

    SETTINGS = PigpioSettings
    settings: PigpioSettings

    def __init__(self, options: Mapping[str, Any], *, max_wheel_speed: float) -> None:
        super().__init__(options, max_wheel_speed=max_wheel_speed)
        s = self.settings
        self.full_duty_speed = s.max_wheel_speed or max_wheel_speed
        self.sides = (self._side("left"), self._side("right"))
        check_pins(s, self._pin_keys(), self.name())
        self.hw_pins = self._hardware_pwm_pins()
        self.decoders = (QuadratureDecoder(), QuadratureDecoder())
        self.deadman = Deadman(s.deadman_s)
        self._decoder_lock = threading.Lock()
        self._write_lock = threading.Lock()  # duty writes: the worker thread and emergency_stop()
        self._pi: Any = None
        self._io: SerialExecutor | None = None
        self._watch = PigpiodWatch(self, s.watch_interval, self._peer, self._lost)
        self._written: dict[int, int] = {}
        self._callbacks: list[Any] = []
        self.connects = 0
        self.real_pwm_frequency: dict[int, int] = {}
        self.pigpio_version: int | None = None
        self.hardware_revision: str | None = None

    def _side(self, name: str) -> Side:
        s = self.settings

        def key(suffix: str) -> Any:
            return getattr(s, f"{name}_{suffix}")

        return Side(name, key("pwm"), key("in1"), key("in2"), key("motor_inverted"),
                    s.encoder_pins(name), key("encoder_inverted"))

    def _pin_keys(self) -> list[str]:
        keys = [f"{side}_{pin}" for side in ("left", "right") for pin in ("pwm", "in1", "in2")]
        return keys + self.settings.encoder_pin_keys()

    def _hardware_pwm_pins(self) -> set[int]:
        if not self.settings.hardware_pwm:
            return set()
        pins = {s.pwm for s in self.sides if s.pwm in HARDWARE_PWM_CHANNEL}
        channels = [HARDWARE_PWM_CHANNEL[p] for p in pins]
        if len(channels) != len(set(channels)):
            raise ValueError(
                f"[driver.pigpio] left_pwm={self.sides[0].pwm} and right_pwm={self.sides[1].pwm} "
                "share one hardware PWM channel; use 12/18 for one side and 13/19 for the other, "
                "or set hardware_pwm = false")
        return pins

    # -- lifecycle ----------------------------------------------------------------------------

    async def _open(self) -> None:
        self._io = SerialExecutor("pigpio")
        try:
            await self._io.call(self._connect)
        except BaseException:
            self._io.shutdown()
            self._io = None
            raise
        self._watch.start("pigpio-watch")

    def _connect(self) -> None:
        s = self.settings
        pi = connect_pigpio(s.host, s.port, s.timeout)
        try:
            self.pigpio_version = pi.get_pigpio_version()
            self.hardware_revision = f"{pi.get_hardware_revision():x}"
            self._written = {}
            for side in self.sides:
                self._setup_side(pi, side)
            self._callbacks = [self._setup_encoder(pi, i, s) for i, s in enumerate(self.sides)
                               if s.encoder is not None]
            self.deadman.start(pi, [(side.pwm, self.settings.pwm_frequency
                                     if side.pwm in self.hw_pins else 0) for side in self.sides],
                               [pin for side in self.sides for pin in (side.in1, side.in2)])
        except Exception as exc:
            drop_pigpio(pi, peer_alive=True)
            raise DriverFault(f"pigpiod at {self._where()}: setup failed: {exc}") from exc
        self._pi = pi
        self.connects += 1

    def _setup_side(self, pi: Any, side: Side) -> None:
        for pin in (side.in1, side.in2):
            pi.set_mode(pin, MODE_OUTPUT)
            self._write_pin(pi, pin, 0)
        if side.pwm in self.hw_pins:
            pi.hardware_PWM(side.pwm, self.settings.pwm_frequency, 0)
            self.real_pwm_frequency[side.pwm] = self.settings.pwm_frequency
        else:
            pi.set_mode(side.pwm, MODE_OUTPUT)
            self.real_pwm_frequency[side.pwm] = pi.set_PWM_frequency(
                side.pwm, self.settings.pwm_frequency)
            pi.set_PWM_range(side.pwm, self.settings.pwm_range)
            pi.set_PWM_dutycycle(side.pwm, 0)
        self._written[side.pwm] = 0

    def _setup_encoder(self, pi: Any, index: int, side: Side) -> Any:
        assert side.encoder is not None
        pin_a, pin_b = side.encoder
        for pin in (pin_a, pin_b):
            pi.set_mode(pin, MODE_INPUT)
            pi.set_pull_up_down(pin, PUD_UP)
            pi.set_glitch_filter(pin, self.settings.glitch_filter_us)
        levels = {pin_a: pi.read(pin_a), pin_b: pi.read(pin_b)}
        decoder = self.decoders[index]
        with self._decoder_lock:
            decoder.reset_levels(levels[pin_a], levels[pin_b])

        def on_edge(gpio: int, level: int, tick: int) -> None:
            if level == PI_TIMEOUT_LEVEL:
                return
            with self._decoder_lock:
                levels[gpio] = level
                decoder.update(levels[pin_a], levels[pin_b])

        return [pi.callback(pin, EITHER_EDGE, on_edge) for pin in (pin_a, pin_b)]

    async def _close(self) -> None:
        await self._watch.stop()
        io, self._io = self._io, None
        if io is not None:
            with contextlib.suppress(Exception):
                await io.call(self._disconnect)
            io.shutdown()

    def _disconnect(self) -> None:
        pi, self._pi = self._pi, None
        self._callbacks = []
        if pi is not None and self.fault is None:
            with contextlib.suppress(Exception):
                self.deadman.stop(pi)
        self.deadman.script_id = None
        if pi is not None:
            drop_pigpio(pi, peer_alive=self.fault is None)

    # -- commands -----------------------------------------------------------------------------

    def rest_hold_s(self) -> float:
        """Fed at least four times per deadman period: at rest the script never fires."""
        return self.deadman.seconds / 4 if self.deadman.enabled else math.inf

    async def _apply(self, left_rad_s: float, right_rad_s: float) -> None:
        duties = (self._duty(left_rad_s, self.sides[0]), self._duty(right_rad_s, self.sides[1]))
        if self._io is None:
            raise DriverFault("pigpio: not connected")
        await self._io.call(self._write_duties_locked, duties)

    def _duty(self, speed: float, side: Side) -> float:
        duty = self.settings.duty(speed, self.full_duty_speed)
        return -duty if side.invert else duty

    def _write_duties(self, duties: tuple[float, float]) -> None:
        pi = self._pi
        if pi is None:
            raise DriverFault("pigpio: connection already lost")
        import pigpio

        try:
            if self.deadman.feed(pi):
                self._written = {}  # the script may have zeroed the pins: write them all
            for side, duty in zip(self.sides, duties, strict=True):
                self._write_side(pi, side, duty)
        except DriverFault:
            raise
        except pigpio.error as exc:  # pigpiod answered with an error: still there to be zeroed
            self._written = {}
            raise DriverFault(f"pigpiod refused a write: {exc}") from exc
        except Exception as exc:
            self._lost(pi, f"write failed: {describe_io_error(exc)}")
            raise DriverFault(self.fault or "pigpiod lost") from exc

    def _write_side(self, pi: Any, side: Side, duty: float) -> None:
        forward, backward = (1, 0) if duty > 0 else ((0, 1) if duty < 0 else (0, 0))
        if (self._written.get(side.in1), self._written.get(side.in2)) != (forward, backward) \
                and self._written.get(side.pwm):
            self._write_pwm(pi, side.pwm, 0.0)  # no full-power glitch while direction flips
        self._write_pin(pi, side.in1, forward)
        self._write_pin(pi, side.in2, backward)
        self._write_pwm(pi, side.pwm, abs(duty))

    def _write_pin(self, pi: Any, pin: int, level: int) -> None:
        if self._written.get(pin) != level:
            pi.write(pin, level)
            self._written[pin] = level

    def _write_pwm(self, pi: Any, pin: int, duty: float) -> None:
        if pin in self.hw_pins:
            value = round(duty * HARDWARE_DUTY_FULL)
            if self._written.get(pin) != value:
                pi.hardware_PWM(pin, self.settings.pwm_frequency, value)
        else:
            value = round(duty * self.settings.pwm_range)
            if self._written.get(pin) != value:
                pi.set_PWM_dutycycle(pin, value)
        self._written[pin] = value

    # -- faults -------------------------------------------------------------------------------

    def _lost(self, pi: Any, reason: str) -> None:
        """pigpiod is gone: mark the fault and stop the client's notification thread now."""
        self.report_fault(f"pigpiod at {self._where()} lost: {reason}")
        drop_pigpio(pi, peer_alive=False)

    def _peer(self) -> tuple[Call, Any] | None:
        """What the keep-alive asks: the worker thread and the client, while connected."""
        pi, io = self._pi, self._io
        if pi is None or io is None:
            return None
        return io.call, pi

    # -- encoders and health ------------------------------------------------------------------

    def _read_encoders(self) -> EncoderReading | None:
        if not self.settings.encoders:
            return None
        left, right = (self._position(i) for i in range(2))
        return EncoderReading(left, right, time.monotonic())

    def _position(self, index: int) -> float:
        side, decoder = self.sides[index], self.decoders[index]
        with self._decoder_lock:
            count = decoder.count
        sign = -1.0 if side.encoder_invert else 1.0
        return sign * count / self.settings.encoder_counts_per_rev * 2.0 * math.pi

    def _where(self) -> str:
        return f"{self.settings.host}:{self.settings.port}"

    def _health(self) -> dict[str, Any]:
        return {
            "pigpiod": self._where(),
            "connects": self.connects,
            "pigpio_version": self.pigpio_version,
            "hardware_revision": self.hardware_revision,
            "hardware_pwm_pins": sorted(self.hw_pins),
            "pwm_frequency_hz": {str(k): v for k, v in self.real_pwm_frequency.items()},
            "encoder_counts": [d.count for d in self.decoders] if self.settings.encoders
            else None,
            "encoder_errors": sum(d.errors for d in self.decoders),
            "deadman_s": self.deadman.seconds if self.deadman.script_id is not None else None,
        }

    # -- emergency path (any thread) -----------------------------------------------------------

    def _write_duties_locked(self, duties: tuple[float, float]) -> None:
        with self._write_lock:
            self._write_duties(duties)

    def _emergency_zero(self) -> bool:
        """Duty 0 on both PWM pins, then both direction pins low, on the driver's connection.

        pigpio's client locks each command on its socket, and the write lock keeps these
        writes from interleaving with the worker thread's; each command waits at most
        ``timeout`` for pigpiod's reply.
        """
        if not self._write_lock.acquire(timeout=self.settings.timeout):
            return False
        try:
            pi = self._pi
            if pi is None or not pi.connected:
                return False
            self._written = {}  # whatever happens next, the next write sends every pin
            for side in self.sides:
                if side.pwm in self.hw_pins:
                    pi.hardware_PWM(side.pwm, self.settings.pwm_frequency, 0)
                else:
                    pi.set_PWM_dutycycle(side.pwm, 0)
            for side in self.sides:
                pi.write(side.in1, 0)
                pi.write(side.in2, 0)
            self._written = {pin: 0 for side in self.sides
                             for pin in (side.pwm, side.in1, side.in2)}
            return True
        finally:
            self._write_lock.release()


def check_pins(settings: object, keys: list[str], section: str) -> None:
    """Refuse a GPIO used twice, naming both config keys (negative = not wired)."""
    seen: dict[int, str] = {}
    for key in keys:
        pin = getattr(settings, key)
        if pin < 0:
            continue
        if pin in seen:
            raise ValueError(f"[driver.{section}] {key} = {pin} is already used by {seen[pin]}")
        seen[pin] = key
