# Servos on numbered outputs (GPIO pins, PWM-board channels): per-joint calibration, pulses out.
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from base.options import option, shared_option
from drivers.devices import Actuator, Joint
from drivers.servo_pulses import PULSE_MAX_US, PULSE_MIN_US, ServoCalibration

#: the calibration keys the servo devices and the [arm] section share, declared once
MIN_PULSE_US = shared_option(500, "pulse width at the lowest position, µs",
                             minval=PULSE_MIN_US, maxval=PULSE_MAX_US)
MAX_PULSE_US = shared_option(2500, "pulse width at the highest position, µs",
                             minval=PULSE_MIN_US, maxval=PULSE_MAX_US)
JOINT_MIN_PULSE_US = shared_option([], "per joint, in joint order: the pulse at its lowest "
                                   "position, µs ([] = min_pulse_us for every joint)",
                                   minval=PULSE_MIN_US, maxval=PULSE_MAX_US)
JOINT_MAX_PULSE_US = shared_option([], "per joint, in joint order: the pulse at its highest "
                                   "position, µs ([] = max_pulse_us for every joint)",
                                   minval=PULSE_MIN_US, maxval=PULSE_MAX_US)
OFFSETS_US = shared_option([], "per joint, in joint order: zero trim added to its pulse, µs "
                           "([] = none)", minval=-500, maxval=500)
REVERSED = shared_option([], "per joint, in joint order: true when the servo turns the other "
                         "way (upper at the min pulse; [] = none)")


@dataclass(frozen=True)
class CalibrationSettings:
    """The keys every servo device shares (the outputs' key is the backend's own: pins,
    channels); each backend's settings add theirs."""

    joints: list[str] = option(["joint1"], "joint names, one per servo")
    lower: list[float] = option([-math.pi / 2], "each joint's lowest position, rad (m for a "
                                "gripper's opening), at its min pulse")
    upper: list[float] = option([math.pi / 2], "each joint's highest position, rad (m for a "
                                "gripper's opening), at its max pulse")
    min_pulse_us: int = option(**MIN_PULSE_US)
    max_pulse_us: int = option(**MAX_PULSE_US)
    joint_min_pulse_us: list[int] = option(**JOINT_MIN_PULSE_US)
    joint_max_pulse_us: list[int] = option(**JOINT_MAX_PULSE_US)
    offsets_us: list[int] = option(**OFFSETS_US)
    reversed: list[bool] = option(**REVERSED)


class ServoArray(Actuator):
    """Hobby servos on numbered outputs, one per joint. Checks the per-joint lists (one entry
    per joint, no output twice, each calibration usable) and turns positions into pulse widths;
    a backend sends them (``_send_pulses``: output => µs, 0 = pulses off)."""

    #: the key naming each joint's output, and what one output is called
    OUTPUTS_KEY: ClassVar[str]
    OUTPUT_NOUN: ClassVar[str]

    def __init__(self, options: Mapping[str, Any], *, section: str) -> None:
        super().__init__(options, section=section)
        s = self.settings
        outputs: list[int] = getattr(s, self.OUTPUTS_KEY)
        self._check_lengths(s, outputs)
        if len(set(s.joints)) != len(s.joints):
            raise ValueError(f"[{section}] joints: a name is used twice: {s.joints}")
        if len(set(outputs)) != len(outputs):
            raise ValueError(f"[{section}] {self.OUTPUTS_KEY}: {self.OUTPUT_NOUN} is used "
                             f"twice: {outputs}")
        if s.min_pulse_us >= s.max_pulse_us:
            raise ValueError(f"[{section}] min_pulse_us must be below max_pulse_us")
        self.calibrations = self._calibrations(s)
        self._joints = tuple(Joint(n, c.lower, c.upper) for n, c in self.calibrations.items())
        self.outputs: dict[str, int] = dict(zip(s.joints, outputs, strict=True))

    def _check_lengths(self, s: Any, outputs: list[int]) -> None:
        if not s.joints:
            raise ValueError(f"[{self.section}] joints: name at least one joint")
        lengths = {len(s.joints), len(outputs), len(s.lower), len(s.upper)}
        if len(lengths) != 1:
            raise ValueError(f"[{self.section}] joints, {self.OUTPUTS_KEY}, lower and upper "
                             f"need one entry per joint (got {len(s.joints)}, {len(outputs)}, "
                             f"{len(s.lower)}, {len(s.upper)})")
        for key in ("joint_min_pulse_us", "joint_max_pulse_us", "offsets_us", "reversed"):
            given = getattr(s, key)
            if given and len(given) != len(s.joints):
                raise ValueError(f"[{self.section}] {key}: one entry per joint or none (got "
                                 f"{len(given)} for {len(s.joints)} joints)")

    def _calibrations(self, s: Any) -> dict[str, ServoCalibration]:
        count = len(s.joints)
        mins = s.joint_min_pulse_us or [s.min_pulse_us] * count
        maxs = s.joint_max_pulse_us or [s.max_pulse_us] * count
        offsets = s.offsets_us or [0] * count
        flips = s.reversed or [False] * count
        out = {}
        for i, name in enumerate(s.joints):
            calibration = ServoCalibration(s.lower[i], s.upper[i], mins[i], maxs[i],
                                           offsets[i], flips[i])
            problems = calibration.problems()
            if problems:
                raise ValueError(f"[{self.section}] joint {name}: {problems[0]}")
            out[name] = calibration
        return out

    def joints(self) -> tuple[Joint, ...]:
        return self._joints

    def pulses_for(self, targets: Mapping[str, float]) -> dict[int, float]:
        """Output => pulse width (µs, unrounded) of already-checked targets."""
        return {self.outputs[name]: self.calibrations[name].pulse_us(value)
                for name, value in targets.items()}

    async def _write(self, targets: dict[str, float]) -> None:
        await self._send_pulses(self.pulses_for(targets))

    async def _relax(self) -> None:
        await self._send_pulses(dict.fromkeys(self.outputs.values(), 0.0))

    async def _send_pulses(self, pulses: dict[int, float]) -> None:
        raise NotImplementedError

    async def probe(self) -> None:
        """Check that the outputs answer without changing a pulse (``arbiterd check``);
        ``DeviceError`` saying why not. The device is closed afterwards."""
        try:
            await self._probe()
        finally:
            await self.close()

    async def _probe(self) -> None:
        await self.open()
