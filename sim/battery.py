# The simulated battery: capacity, open-circuit voltage curve, internal resistance, load and dock.
from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

#: a Li-ion (NMC) cell's open-circuit voltage by state of charge, at rest (V)
LIION_SOC = (0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
LIION_OCV = (3.0, 3.3, 3.45, 3.55, 3.62, 3.68, 3.73, 3.80, 3.88, 3.96, 4.06, 4.20)
#: the charger's constant voltage per cell, V
CHARGE_CELL_V = 4.2


@dataclass(frozen=True)
class BatterySpec:
    """A pack: ``cells`` Li-ion cells in series of ``capacity_ah``; ``resistance_ohm`` the
    pack's internal resistance; ``base_load_a`` what the computer and the lidar draw;
    ``motor_a_per_rad_s`` each wheel's draw per rad/s it turns; ``charge_current_a`` the
    dock's constant-current limit; ``drain`` multiplies every load (a test drains it fast)."""

    cells: int = 3
    capacity_ah: float = 2.6
    resistance_ohm: float = 0.12
    base_load_a: float = 0.8
    motor_a_per_rad_s: float = 0.03
    charge_current_a: float = 2.0
    drain: float = 1.0


def open_circuit_v(soc: float, cells: int) -> float:
    """The pack's resting voltage at state of charge ``soc`` (0..1)."""
    return cells * float(np.interp(min(max(soc, 0.0), 1.0), LIION_SOC, LIION_OCV))


def soc_of_voltage(volts: float, cells: int) -> float:
    """The state of charge (0..1) whose resting voltage is ``volts`` (the curve inverted)."""
    return float(np.interp(volts / cells, LIION_OCV, LIION_SOC))


class BatteryModel:
    """A pack stepped with the world: the load is ``base_load_a`` plus each wheel's speed times
    ``motor_a_per_rad_s``; on the dock the charger pushes up to ``charge_current_a`` (constant
    current, then constant voltage as the pack nears full). :meth:`measure` gives what a monitor
    on the pack reads: terminal voltage (V) and current (A, positive out of the pack into the
    robot; negative while it charges). Thread-safe."""

    def __init__(self, spec: BatterySpec | None = None, soc: float = 1.0) -> None:
        self.spec = spec or BatterySpec()
        self.soc = min(max(soc, 0.0), 1.0)
        self.on_dock = False
        self.load_a = self.spec.base_load_a
        self.current_a = self.load_a
        #: ampere-hours drawn and put back since it was built
        self.drawn_ah = 0.0
        self.charged_ah = 0.0
        self._lock = threading.Lock()

    def step(self, dt: float, wheel_speeds: tuple[float, float], on_dock: bool) -> None:
        spec = self.spec
        load = spec.drain * (spec.base_load_a + spec.motor_a_per_rad_s
                             * (abs(wheel_speeds[0]) + abs(wheel_speeds[1])))
        with self._lock:
            self.on_dock, self.load_a = on_dock, load
            charge = self._charge_current() if on_dock else 0.0
            self.current_a = load - charge
            self.soc = min(max(self.soc - self.current_a * dt / 3600.0 / spec.capacity_ah,
                               0.0), 1.0)
            if self.current_a > 0:
                self.drawn_ah += self.current_a * dt / 3600.0
            else:
                self.charged_ah -= self.current_a * dt / 3600.0

    def _charge_current(self) -> float:
        """Constant current until the terminal voltage would pass the charger's, then what
        that voltage pushes through the internal resistance (tapering to nothing when full);
        the charger also feeds the robot's load."""
        spec = self.spec
        headroom = (spec.cells * CHARGE_CELL_V - open_circuit_v(self.soc, spec.cells))
        into_pack = min(spec.charge_current_a, max(headroom / spec.resistance_ohm, 0.0))
        return self.load_a + into_pack if self.soc < 1.0 else self.load_a

    def measure(self) -> tuple[float, float]:
        """(terminal voltage V, current A out of the pack)."""
        with self._lock:
            ocv = open_circuit_v(self.soc, self.spec.cells)
            return ocv - self.current_a * self.spec.resistance_ohm, self.current_a

    def set_soc(self, soc: float) -> None:
        with self._lock:
            self.soc = min(max(soc, 0.0), 1.0)

    def report(self) -> dict[str, float | bool]:
        volts, amps = self.measure()
        return {"soc": round(self.soc, 5), "voltage": round(volts, 4),
                "current": round(amps, 4), "on_dock": self.on_dock,
                "drawn_ah": round(self.drawn_ah, 4), "charged_ah": round(self.charged_ah, 4)}
