# Hobby-servo calibration: a joint position <-> a pulse width (µs). Pure: shared with the emulators.
from __future__ import annotations

from dataclasses import dataclass

#: the pulse widths a hobby servo takes (0 turns the pulses off)
PULSE_MIN_US, PULSE_MAX_US = 500, 2500
#: the servo frame rate, Hz
SERVO_HZ = 50.0


@dataclass(frozen=True)
class ServoCalibration:
    """How one joint's position maps onto its servo's pulse: ``lower``..``upper`` (rad, or m
    for a gripper's opening) linearly onto ``min_us``..``max_us`` (``reversed``: ``upper`` at
    ``min_us``), then ``offset_us`` added (the horn's zero trim)."""

    lower: float
    upper: float
    min_us: int = PULSE_MIN_US
    max_us: int = PULSE_MAX_US
    offset_us: int = 0
    reversed: bool = False

    def pulse_us(self, position: float) -> float:
        """The pulse width (µs, unrounded) that holds ``position``."""
        fraction = (position - self.lower) / (self.upper - self.lower)
        if self.reversed:
            fraction = 1.0 - fraction
        return self.min_us + fraction * (self.max_us - self.min_us) + self.offset_us

    def position(self, pulse_us: float) -> float:
        """The position a servo at ``pulse_us`` holds (the inverse of :meth:`pulse_us`)."""
        fraction = (pulse_us - self.offset_us - self.min_us) / (self.max_us - self.min_us)
        if self.reversed:
            fraction = 1.0 - fraction
        return self.lower + fraction * (self.upper - self.lower)

    def problems(self) -> list[str]:
        """What is wrong with this calibration (empty when it is usable)."""
        found = []
        if not self.lower < self.upper:
            found.append(f"lower ({self.lower}) must be below upper ({self.upper})")
        if not self.min_us < self.max_us:
            found.append(f"min pulse ({self.min_us} µs) must be below max pulse "
                         f"({self.max_us} µs)")
        ends = (self.min_us + self.offset_us, self.max_us + self.offset_us)
        if min(ends) < PULSE_MIN_US or max(ends) > PULSE_MAX_US:
            found.append(f"pulses with the offset ({ends[0]}..{ends[1]} µs) leave "
                         f"{PULSE_MIN_US}..{PULSE_MAX_US} µs")
        return found
