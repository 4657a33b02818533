# [battery]: the monitor (INA219, INA226, an ODrive, the simulated pack), the pack, the policy.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import Option, Options
from drivers.ina2xx import INA_OPTIONS
from drivers.odrive_battery import ODRIVE_BATTERY_OPTIONS

#: device option => the device (drivers/device_registry.py) it is; sim reads the simulator's pack
DEVICES = {"ina219": "ina219", "ina226": "ina226", "odrive_can": "odrive_battery", "sim": ""}


def _ascending(values: list[float]) -> str | None:
    return None if values == sorted(values) else "expected ascending voltages"


BATTERY_OPTIONS: Options = {
    "enabled": Option(bool, False, "watch the battery: /battery_state, GET /api/battery, the "
                      "power policy"),
    "device": Option(str, "ina219", "what measures it: ina219 or ina226 (over I2C), odrive_can "
                     "(the wheels' ODrive's DC bus), sim (the simulator's pack; run --sim "
                     "also emulates the chips against it)", choices=tuple(DEVICES)),
    **INA_OPTIONS,
    **{k: v for k, v in ODRIVE_BATTERY_OPTIONS.items() if k not in ("timeout_s",)},
    "timeout_s": Option(float, 1.0, "ina219/ina226: each transfer on an emulated bus; "
                        "odrive_can: each request's answer, s", above=0.0, maxval=30.0),
    "rate": Option(float, 2.0, "readings per second", minval=0.1, maxval=50.0),
    "cells": Option(int, 3, "cells in series", minval=1, maxval=24),
    "cell_curve": Option(list, [3.0, 3.45, 3.55, 3.62, 3.68, 3.73, 3.80, 3.88, 3.96, 4.06,
                                4.20],
                         "a cell's resting voltage at 0, 10, ..., 100 % (this: Li-ion; "
                         "LiFePO4: 2.5, 3.0, 3.2, 3.22, 3.25, 3.27, 3.29, 3.3, 3.32, 3.34, "
                         "3.36, 3.6)", item=float, length=11, minval=0.5, maxval=5.0,
                         check=_ascending),
    "capacity_ah": Option(float, 2.6, "the pack's capacity, Ah", above=0.0, maxval=10000.0),
    "internal_resistance_ohm": Option(float, 0.12, "the pack's internal resistance, ohm: "
                                      "the charge is read from the voltage the pack would "
                                      "have at rest (V + I R)", minval=0.0, maxval=10.0),
    "smoothing_s": Option(float, 10.0, "time constant of the charge estimate, s (a motor's "
                          "surge must not trip the policy)", minval=0.0, maxval=600.0),
    "charging_current_a": Option(float, 0.05, "a current into the pack above this is "
                                 "charging, A", above=0.0),
    "low": Option(float, 0.20, "below this charge: warn (health degraded, the console's "
                  "banner) and go home when the current task ends, 0..1", minval=0.0,
                  maxval=1.0),
    "very_low": Option(float, 0.15, "below this: refuse new goals, missions and fetches "
                       "(409 naming the charge) and go home now", minval=0.0, maxval=1.0),
    "critical": Option(float, 0.12, "below this: stop the motors, close the recording and "
                       "save the map, then run shutdown_command", minval=0.0, maxval=1.0),
    "hysteresis": Option(float, 0.03, "a level clears only this far above its threshold "
                         "(or while charging)", minval=0.0, maxval=0.5),
    "shutdown_command": Option(list, [], "run at critical, after the files are closed "
                               "(e.g. [\"systemctl\", \"poweroff\"]); [] = none", item=str),
    "shutdown_delay_s": Option(float, 60.0, "critical and not charging for this long before "
                               "shutdown_command runs (docking cancels it), s", minval=0.0,
                               maxval=3600.0),
}


@dataclass(frozen=True)
class BatterySettings(SectionSettings, section="battery", options=BATTERY_OPTIONS):
    enabled: bool
    device: str
    bus: str
    address: int
    shunt_ohms: float
    max_current_a: float
    interface: str
    channel: str
    node_id: int
    timeout_s: float
    rate: float
    cells: int
    cell_curve: list[float]
    capacity_ah: float
    internal_resistance_ohm: float
    smoothing_s: float
    charging_current_a: float
    low: float
    very_low: float
    critical: float
    hysteresis: float
    shutdown_command: list[str]
    shutdown_delay_s: float

    def problems(self) -> list[str]:
        if not self.critical <= self.very_low <= self.low:
            return [f"[battery] critical ({self.critical}) <= very_low ({self.very_low}) <= "
                    f"low ({self.low}) is expected"]
        return []
