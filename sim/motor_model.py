# Shared wheel motor model for every emulator: first-order response, saturation, encoder counts,
# and how the motors and encoders are wired (a mirrored mount, or a wiring fault to play).
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

#: Wiring faults the emulated hardware can play (``[sim] miswire``).
MISWIRES = ("left_motor_reversed", "right_motor_reversed", "left_encoder_reversed",
            "right_encoder_reversed", "left_encoder_dead", "right_encoder_dead", "sides_swapped")


@dataclass
class WheelMotor:
    """One wheel driven by a DC motor, seen from outside as a first-order velocity response.

    ``target_rad_s`` is what the controller asks for (a duty cycle maps to
    ``duty * max_speed_rad_s``); ``speed_rad_s`` follows it with time constant
    ``time_constant_s`` and saturates at ``max_speed_rad_s``. ``position_rad`` integrates the
    speed; ``counts`` is what a quadrature encoder with ``counts_per_rev`` would read.
    ``direction`` is -1 for a wheel mounted mirrored (its encoder counts down going forward).
    """

    max_speed_rad_s: float = 40.0
    time_constant_s: float = 0.05
    counts_per_rev: int = 1440
    direction: int = 1
    target_rad_s: float = 0.0
    speed_rad_s: float = 0.0
    position_rad: float = 0.0

    def set_target(self, rad_s: float) -> None:
        self.target_rad_s = max(-self.max_speed_rad_s, min(self.max_speed_rad_s, rad_s))

    def set_duty(self, duty: float) -> None:
        """Drive with a duty cycle in -1..1 (open loop)."""
        self.set_target(max(-1.0, min(1.0, duty)) * self.max_speed_rad_s)

    def advance(self, dt: float) -> None:
        """Step the motor ``dt`` seconds (exact solution of the first-order lag)."""
        if dt <= 0:
            return
        start = self.speed_rad_s
        alpha = 1.0 - math.exp(-dt / self.time_constant_s) if self.time_constant_s > 0 else 1.0
        self.speed_rad_s = start + (self.target_rad_s - start) * alpha
        # integral of the exponential approach over dt
        if self.time_constant_s > 0:
            lag = (start - self.target_rad_s) * self.time_constant_s * alpha
            moved = self.target_rad_s * dt + lag
        else:
            moved = self.target_rad_s * dt
        self.position_rad += moved

    @property
    def counts(self) -> int:
        turns = self.position_rad / (2 * math.pi)
        return self.direction * math.floor(turns * self.counts_per_rev)


@dataclass(frozen=True)
class PairWiring:
    """How the controller's two output channels and two encoder inputs meet the wheels.

    ``motor_signs[w]`` is -1 when wheel ``w``'s motor turns it backward for a forward drive;
    ``encoder_signs[c]`` is -1 when encoder input ``c`` counts down going forward, 0 when it
    counts nothing (dead); with ``swapped`` each output channel drives the other side's motor
    (the encoders stay on their own sides). Channel and wheel 0 are left, 1 right.
    """

    motor_signs: tuple[int, int] = (1, 1)
    encoder_signs: tuple[int, int] = (1, 1)
    swapped: bool = False

    @classmethod
    def build(cls, motor_inverted: tuple[bool, bool] = (False, False),
              encoder_inverted: tuple[bool, bool] = (False, False),
              miswire: Iterable[str] = ()) -> PairWiring:
        """Hardware mounted so that a driver with these inversion settings drives it right,
        then the ``miswire`` faults on top (names from :data:`MISWIRES`)."""
        faults = set(miswire)
        unknown = sorted(faults - set(MISWIRES))
        if unknown:
            raise ValueError(f"unknown miswire {unknown[0]!r}; valid: {', '.join(MISWIRES)}")

        def sign(inverted: bool, fault: str) -> int:
            return (-1 if inverted else 1) * (-1 if fault in faults else 1)

        sides = ("left", "right")
        motors = tuple(sign(motor_inverted[i], f"{s}_motor_reversed") for i, s in enumerate(sides))
        encoders = tuple(0 if f"{s}_encoder_dead" in faults
                         else sign(encoder_inverted[i], f"{s}_encoder_reversed")
                         for i, s in enumerate(sides))
        return cls((motors[0], motors[1]), (encoders[0], encoders[1]), "sides_swapped" in faults)

    def wheel_of(self, channel: int) -> int:
        """The wheel an output channel drives."""
        return 1 - channel if self.swapped else channel

    def wheel_duties(self, left: float, right: float) -> tuple[float, float]:
        """The duty each wheel's motor sees when the output channels carry these."""
        duties = [0.0, 0.0]
        for channel, duty in enumerate((left, right)):
            wheel = self.wheel_of(channel)
            duties[wheel] += self.motor_signs[wheel] * duty
        return duties[0], duties[1]

    def closed_loop(self, channel: int, target: float, max_speed: float) -> tuple[int, float]:
        """(wheel, its speed) when a controller drives ``channel`` toward ``target`` as read on
        encoder input ``channel``: an ideal loop where motor and encoder agree; saturation in
        the target's direction where they disagree, the encoder is dead or the output drives
        the other side (the controller never sees its output move its input)."""
        wheel = self.wheel_of(channel)
        gain = self.motor_signs[wheel] * self.encoder_signs[channel]
        if wheel == channel and gain == 1:
            return wheel, target * self.encoder_signs[channel]
        if target == 0:
            return wheel, 0.0
        return wheel, self.motor_signs[wheel] * math.copysign(max_speed, target)


class MotorPair:
    """Left and right wheel motors advanced together, either by the world or by real time.

    Emulators read and command the motors through this object. With ``clock`` set (the
    default is ``time.monotonic``), every access first advances the motors to the clock's
    current time, so a standalone emulator needs no thread. The simulated world passes
    ``clock=None`` and calls :meth:`advance` from its own physics step instead.

    ``wiring`` (a :class:`PairWiring`) sits between the emulators and the wheels: commands
    (:meth:`set_duties` open loop, :meth:`set_targets` a controller closing the loop on the
    encoders) and encoder readings (:meth:`counts`, :meth:`encoder_positions`) go through it;
    :meth:`positions`, :meth:`speeds` and :meth:`targets` are the wheels' true motion.
    """

    def __init__(self, left: WheelMotor | None = None, right: WheelMotor | None = None,
                 clock: Callable[[], float] | None = time.monotonic,
                 wiring: PairWiring | None = None) -> None:
        self.left = left or WheelMotor()
        self.right = right or WheelMotor()
        self.wiring = wiring or PairWiring()
        self.lock = threading.RLock()
        self._clock = clock
        self._last = clock() if clock else 0.0

    def sync(self) -> None:
        """Advance to the clock's current time (no-op when the world drives the motors)."""
        if self._clock is None:
            return
        with self.lock:
            now = self._clock()
            self.advance(now - self._last)
            self._last = now

    def advance(self, dt: float) -> None:
        with self.lock:
            self.left.advance(dt)
            self.right.advance(dt)

    def set_targets(self, left_rad_s: float, right_rad_s: float) -> None:
        """A controller on the encoders asks each channel for this speed (rad/s as its
        encoder input reads it)."""
        with self.lock:
            self.sync()
            wheels = (self.left, self.right)
            speeds = [0.0, 0.0]
            for channel, target in enumerate((left_rad_s, right_rad_s)):
                wheel, speed = self.wiring.closed_loop(channel, target,
                                                       wheels[channel].max_speed_rad_s)
                speeds[wheel] += speed
            self.left.set_target(speeds[0])
            self.right.set_target(speeds[1])

    def set_duties(self, left: float, right: float) -> None:
        """Open loop: a duty cycle (-1..1) on each output channel."""
        with self.lock:
            self.sync()
            duties = self.wiring.wheel_duties(left, right)
            self.left.set_duty(duties[0])
            self.right.set_duty(duties[1])

    def turn_by_hand(self, wheel: int, rad: float) -> None:
        """Someone turns one wheel (0 left, 1 right) by ``rad``, forward positive."""
        with self.lock:
            self.sync()
            (self.left, self.right)[wheel].position_rad += rad

    def speeds(self) -> tuple[float, float]:
        with self.lock:
            self.sync()
            return self.left.speed_rad_s, self.right.speed_rad_s

    def targets(self) -> tuple[float, float]:
        with self.lock:
            return self.left.target_rad_s, self.right.target_rad_s

    def positions(self) -> tuple[float, float]:
        with self.lock:
            self.sync()
            return self.left.position_rad, self.right.position_rad

    def counts(self) -> tuple[int, int]:
        """What the encoder inputs read (through the wiring)."""
        with self.lock:
            self.sync()
            signs = self.wiring.encoder_signs
            return signs[0] * self.left.counts, signs[1] * self.right.counts

    def encoder_positions(self) -> tuple[float, float]:
        """Wheel positions (rad) as the encoder inputs read them (through the wiring)."""
        with self.lock:
            self.sync()
            signs = self.wiring.encoder_signs
            return signs[0] * self.left.position_rad, signs[1] * self.right.position_rad

    def encoder_speeds(self) -> tuple[float, float]:
        """Wheel speeds (rad/s) as the encoder inputs read them (through the wiring)."""
        with self.lock:
            self.sync()
            signs = self.wiring.encoder_signs
            return signs[0] * self.left.speed_rad_s, signs[1] * self.right.speed_rad_s


def now() -> float:
    return time.monotonic()
