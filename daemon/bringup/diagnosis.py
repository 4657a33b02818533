# What a wheel's spin and hand turn say about its wiring, and the config lines that fix it (pure).
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

DIAGNOSES = ("ok", "motor_reversed", "encoder_reversed", "no_counts", "sides_swapped",
             "open_loop")
SIDES = ("left", "right")
#: a move counts when it reaches this fraction of what was asked for
MOVED_FRACTION = 0.25
#: a measured counts per revolution this far from the config is worth a fix line
CPR_TOLERANCE = 0.05
#: the motor pins each PWM driver swaps when the motors are on the wrong sides
MOTOR_PIN_KEYS = {"pigpio": ("pwm", "in1", "in2"), "l298n": ("forward", "backward", "enable")}
CPR_KEYS = {"serial": "counts_per_rev", "pigpio": "encoder_counts_per_rev",
            "l298n": "encoder_counts_per_rev"}


@dataclass(frozen=True)
class Spin:
    """One wheel driven alone: what was asked and what both encoders counted (rad)."""

    commanded_rad: float
    own_rad: float
    other_rad: float
    #: which way someone (or the simulation) saw the wheel turn: 1, -1, 0; None = not watched
    watched: int | None = None


@dataclass
class Finding:
    """One side's diagnosis, the wiring it implies, and its figures."""

    side: str
    diagnosis: str
    motor_wrong: bool = False
    encoder_wrong: bool = False
    notes: list[str] = field(default_factory=list)
    figures: dict[str, Any] = field(default_factory=dict)


def sign(value: float) -> int:
    return (value > 0) - (value < 0)


def diagnose(side: str, spin: Spin, hand_rad: float | None) -> Finding:
    """Diagnose one side from its spin and, when the wheel was turned one revolution forward
    by hand, what its encoder counted then (``hand_rad``, rad as configured)."""
    threshold = MOVED_FRACTION * abs(spin.commanded_rad)
    moved, other_moved = abs(spin.own_rad) > threshold, abs(spin.other_rad) > threshold
    if not moved and other_moved:
        return Finding(side, "sides_swapped", notes=[
            f"driving the {side} wheel alone moved the other side's encoder"])
    if hand_rad is not None:
        return _with_hand(side, spin, hand_rad, moved)
    if not moved:
        return _no_counts(side, spin.watched)
    if spin.watched:
        return _from_direction(side, spin.watched, sign(spin.own_rad) * spin.watched)
    finding = _from_direction(side, 1, sign(spin.own_rad))
    finding.notes.append("nobody watched the wheel: its turning direction is assumed right; "
                         "run test-motors in a terminal to check it by hand")
    return finding


def _with_hand(side: str, spin: Spin, hand_rad: float, moved: bool) -> Finding:
    if abs(hand_rad) < MOVED_FRACTION * 2 * math.pi:
        return Finding(side, "no_counts", notes=[
            f"turning the {side} wheel by hand did not move its encoder"])
    if not moved:
        return Finding(side, "no_counts", notes=[
            f"the {side} encoder counts, but driving the motor did not turn the wheel: check "
            "the motor's power and its two wires"])
    encoder = sign(hand_rad)
    return _from_direction(side, sign(spin.own_rad) * encoder, encoder)


def _no_counts(side: str, watched: int | None) -> Finding:
    if watched == 0:
        return Finding(side, "no_counts", notes=[
            f"the {side} wheel did not turn and its encoder did not count: check the motor's "
            "power and wires first"])
    return Finding(side, "no_counts", notes=[f"the {side} encoder did not count"])


def _from_direction(side: str, wheel: int, encoder: int) -> Finding:
    """``wheel``: which way the wheel turned for a forward command; ``encoder``: which way its
    encoder counts for a forward turn."""
    motor_wrong, encoder_wrong = wheel < 0, encoder < 0
    diagnosis = "motor_reversed" if motor_wrong else (
        "encoder_reversed" if encoder_wrong else "ok")
    finding = Finding(side, diagnosis, motor_wrong, encoder_wrong)
    if motor_wrong and encoder_wrong:
        finding.notes.append(f"the {side} motor and its encoder are both reversed (a mirrored "
                             "mount): flip both")
    return finding


# -- what to change ----------------------------------------------------------------------------


@dataclass
class Fixes:
    """Config lines (one ``[driver.<name>]`` snippet) and wiring steps."""

    lines: dict[str, Any] = field(default_factory=dict)
    rewire: list[str] = field(default_factory=list)

    def config_lines(self, section: str) -> list[str]:
        if not self.lines:
            return []
        return [f"[{section}]", *(f"{key} = {_toml(value)}" for key, value in self.lines.items())]


def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def loop_in_device(driver: str, options: Mapping[str, Any]) -> bool:
    """True where the speed loop runs in the device (its PID reads the encoder itself), so a
    motor against its encoder cannot be fixed from the host."""
    return driver == "odrive_can" or (driver == "serial" and options.get("mode") == "closed_loop")


def fixes_for(driver: str, options: Mapping[str, Any], findings: list[Finding]) -> Fixes:
    """What to change in ``[driver.<driver>]`` (``options``: its effective values)."""
    fixes = Fixes()
    for finding in findings:
        if finding.diagnosis in ("motor_reversed", "encoder_reversed"):
            _flip(fixes, driver, options, finding)
        elif finding.diagnosis == "no_counts":
            fixes.rewire.append(_encoder_check(driver, options, finding.side))
    if any(f.diagnosis == "sides_swapped" for f in findings):
        _swap(fixes, driver, options)
    return fixes


def _flip(fixes: Fixes, driver: str, options: Mapping[str, Any], finding: Finding) -> None:
    side = finding.side
    both = finding.motor_wrong and finding.encoder_wrong
    if both or not loop_in_device(driver, options):
        for part, wrong in (("motor", finding.motor_wrong), ("encoder", finding.encoder_wrong)):
            key = f"{side}_{part}_inverted"
            if wrong and key in options:
                fixes.lines[key] = not options[key]
        return
    if driver == "serial":
        fixes.rewire.append(
            f"swap the {side} motor's two wires at the motor driver's output (the firmware's "
            "PID needs motor and encoder to agree; no setting can)" if finding.motor_wrong else
            f"swap the {side} encoder's A and B wires at the Arduino (the firmware's PID needs "
            "motor and encoder to agree; no setting can)")
    else:
        fixes.rewire.append(f"the ODrive's {side} axis turns against its encoder: check the "
                            "motor phase wires and run the ODrive's motor and encoder "
                            "calibration again")


def _swap(fixes: Fixes, driver: str, options: Mapping[str, Any]) -> None:
    pins = MOTOR_PIN_KEYS.get(driver)
    if pins is None:
        fixes.rewire.append("the motors are on the wrong sides: swap the two motors' "
                            "connectors at the motor driver (the encoders stay where they are)")
        return
    for pin in pins:
        if options[f"left_{pin}"] == options[f"right_{pin}"]:
            continue  # e.g. both enables jumpered
        fixes.lines[f"left_{pin}"] = options[f"right_{pin}"]
        fixes.lines[f"right_{pin}"] = options[f"left_{pin}"]


def _encoder_check(driver: str, options: Mapping[str, Any], side: str) -> str:
    where = ""
    if f"{side}_encoder_a" in options:
        where = (f" (GPIO {options[f'{side}_encoder_a']} and "
                 f"{options[f'{side}_encoder_b']})")
    return (f"check the {side} encoder: its power, ground and A/B wires{where}; then run "
            "test-motors again")


def counts_per_rev_line(driver: str, options: Mapping[str, Any],
                        hand_rad: float) -> tuple[float, int | None, dict[str, int]]:
    """Measured counts per revolution from one hand revolution, the configured value, and the
    fix line when they differ by more than :data:`CPR_TOLERANCE`."""
    key = CPR_KEYS.get(driver)
    configured = int(options[key]) if key else None
    if configured is None:
        return abs(hand_rad) / (2 * math.pi), None, {}
    measured = abs(hand_rad) / (2 * math.pi) * configured
    if abs(measured - configured) > CPR_TOLERANCE * configured:
        return measured, configured, {key: round(measured)} if key else {}
    return measured, configured, {}
