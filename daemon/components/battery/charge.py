# The charge estimate and the policy's levels from voltage and current readings (pure).
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from daemon.components.battery.settings import BatterySettings

LEVELS = ("ok", "low", "very_low", "critical")
#: sensor_msgs/BatteryState power_supply_status by name
STATUS_CODES = {"unknown": 0, "charging": 1, "discharging": 2, "not_charging": 3, "full": 4}
#: a charging pack at or above this is full
FULL = 0.98


@dataclass(frozen=True)
class Reading:
    """One reading and what it means. ``current`` follows BatteryState: negative while the
    pack discharges."""

    stamp: float
    voltage: float
    current: float
    percentage: float
    status: str
    level: str

    def to_json(self) -> dict[str, object]:
        return {"voltage": round(self.voltage, 3), "current": round(self.current, 3),
                "percentage": round(self.percentage, 4), "status": self.status,
                "level": self.level}


class ChargeEstimator:
    """The charge from the voltage the pack would have at rest (V + I R, I drawn), through the
    cell curve, smoothed with a time constant; and the policy level with hysteresis."""

    def __init__(self, settings: BatterySettings) -> None:
        self.settings = settings
        self.curve = np.array(settings.cell_curve) * settings.cells
        self.steps = np.linspace(0.0, 1.0, len(settings.cell_curve))
        self.percentage: float | None = None
        self.level = "ok"
        self._last: float | None = None

    def at_rest(self, volts: float, drawn_a: float) -> float:
        """The charge (0..1) of the pack whose terminal voltage is ``volts`` while ``drawn_a``
        flows out of it."""
        rest = volts + drawn_a * self.settings.internal_resistance_ohm
        return float(np.interp(rest, self.curve, self.steps))

    def update(self, now: float, volts: float, drawn_a: float) -> Reading:
        s = self.settings
        raw = self.at_rest(volts, drawn_a)
        if self.percentage is None or self._last is None or s.smoothing_s <= 0:
            self.percentage = raw
        else:
            alpha = 1.0 - math.exp(-max(now - self._last, 0.0) / s.smoothing_s)
            self.percentage += alpha * (raw - self.percentage)
        self._last = now
        charging = drawn_a < -s.charging_current_a
        status = ("full" if self.percentage >= FULL else "charging") if charging else \
            "discharging" if drawn_a > s.charging_current_a else "not_charging"
        self.level = self._level(self.percentage, charging)
        return Reading(now, volts, -drawn_a, self.percentage, status, self.level)

    def _level(self, percentage: float, charging: bool) -> str:
        s = self.settings
        thresholds = {"low": s.low, "very_low": s.very_low, "critical": s.critical}
        found = "ok"
        for name in ("low", "very_low", "critical"):
            if percentage < thresholds[name]:
                found = name
        held = self.level
        if LEVELS.index(found) >= LEVELS.index(held) or held == "ok":
            return found
        # going up: only past the threshold plus the hysteresis, or while charging
        if charging or percentage >= thresholds[held] + s.hysteresis:
            return found
        return held
