# [battery]: the monitor (INA219, INA226, an ODrive, the simulated pack), the pack, the policy.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option
from drivers.ina2xx import INA_ADDRESS, INA_BUS, INA_MAX_CURRENT_A, INA_SHUNT_OHMS
from drivers.odrive_battery import ODRIVE_CHANNEL, ODRIVE_INTERFACE, ODRIVE_NODE_ID

#: device option => the device (drivers/device_registry.py) it is; sim reads the simulator's pack
DEVICES = {"ina219": "ina219", "ina226": "ina226", "odrive_can": "odrive_battery", "sim": ""}


def _ascending(values: list[float]) -> str | None:
    return None if values == sorted(values) else "expected ascending voltages"


@dataclass(frozen=True)
class BatterySettings(SectionSettings, section="battery"):
    """The [battery] section: what measures the pack, the pack, and the power policy."""

    enabled: bool = option(False, "watch the battery: /battery_state, GET /api/battery, the "
                           "power policy")
    device: str = option("ina219", "what measures it: ina219 or ina226 (over I2C), odrive_can "
                         "(the wheels' ODrive's DC bus), sim (the simulator's pack; run --sim "
                         "also emulates the chips against it)", choices=tuple(DEVICES))
    bus: str = option(**INA_BUS)
    address: int = option(**INA_ADDRESS)
    shunt_ohms: float = option(**INA_SHUNT_OHMS)
    max_current_a: float = option(**INA_MAX_CURRENT_A)
    interface: str = option(**ODRIVE_INTERFACE)
    channel: str = option(**ODRIVE_CHANNEL)
    node_id: int = option(**ODRIVE_NODE_ID)
    timeout_s: float = option(1.0, "ina219/ina226: each transfer on an emulated bus; "
                              "odrive_can: each request's answer, s", above=0.0, maxval=30.0)
    rate: float = option(2.0, "readings per second", minval=0.1, maxval=50.0)
    cells: int = option(3, "cells in series", minval=1, maxval=24)
    cell_curve: list[float] = option(
        [3.0, 3.45, 3.55, 3.62, 3.68, 3.73, 3.80, 3.88, 3.96, 4.06, 4.20],
        "a cell's resting voltage at 0, 10, ..., 100 % (this: Li-ion; LiFePO4: 2.5, 3.0, 3.2, "
        "3.22, 3.25, 3.27, 3.29, 3.3, 3.32, 3.34, 3.36, 3.6)", length=11, minval=0.5,
        maxval=5.0, check=_ascending)
    capacity_ah: float = option(2.6, "the pack's capacity, Ah", above=0.0, maxval=10000.0)
    internal_resistance_ohm: float = option(0.12, "the pack's internal resistance, ohm: the "
                                            "charge is read from the voltage the pack would "
                                            "have at rest (V + I R)", minval=0.0, maxval=10.0)
    smoothing_s: float = option(10.0, "time constant of the charge estimate, s (a motor's "
                                "surge must not trip the policy)", minval=0.0, maxval=600.0)
    charging_current_a: float = option(0.05, "a current into the pack above this is charging, "
                                       "A", above=0.0)
    low: float = option(0.20, "below this charge: warn (health degraded, the console's banner) "
                        "and go home when the current task ends, 0..1", minval=0.0, maxval=1.0)
    very_low: float = option(0.15, "below this: refuse new goals, missions and fetches (409 "
                             "naming the charge) and go home now", minval=0.0, maxval=1.0)
    critical: float = option(0.12, "below this: stop the motors, close the recording and save "
                             "the map, then run shutdown_command", minval=0.0, maxval=1.0)
    hysteresis: float = option(0.03, "a level clears only this far above its threshold (or "
                               "while charging)", minval=0.0, maxval=0.5)
    shutdown_command: list[str] = option([], "run at critical, after the files are closed "
                                         "(e.g. [\"systemctl\", \"poweroff\"]); [] = none")
    shutdown_delay_s: float = option(60.0, "critical and not charging for this long before "
                                     "shutdown_command runs (docking cancels it), s",
                                     minval=0.0, maxval=3600.0)

    def problems(self) -> list[str]:
        if not self.critical <= self.very_low <= self.low:
            return [f"[battery] critical ({self.critical}) <= very_low ({self.very_low}) <= "
                    f"low ({self.low}) is expected"]
        return []
