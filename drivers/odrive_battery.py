# A battery's voltage and current as an ODrive on CAN measures its DC bus (Get_Bus_Voltage_Current).
from __future__ import annotations

import asyncio
import threading
import time
from dataclasses import dataclass
from typing import Any

import can

from base.options import option, shared_option
from drivers.cansimple import (
    CMD_GET_BUS_VOLTAGE_CURRENT,
    MAX_NODE_ID,
    FrameError,
    arbitration_id,
    decode_bus_voltage_current,
)
from drivers.devices import DeviceError, Sensor

#: the keys of the ODrive's bus monitor, declared once (the [battery] section has them too)
ODRIVE_INTERFACE = shared_option("socketcan", "python-can interface of the wheels' ODrive "
                                 "(socketcan on a Pi CAN HAT)")
ODRIVE_CHANNEL = shared_option("can0", "python-can channel (the wheels' [driver.odrive_can] one)")
ODRIVE_NODE_ID = shared_option(0, "the CAN node id of an axis on the ODrive that carries the "
                               "battery (either axis: both see the same DC bus)", minval=0,
                               maxval=MAX_NODE_ID)


@dataclass(frozen=True)
class ODriveBatterySettings:
    """An odrive_battery device's keys."""

    interface: str = option(**ODRIVE_INTERFACE)
    channel: str = option(**ODRIVE_CHANNEL)
    node_id: int = option(**ODRIVE_NODE_ID)
    timeout_s: float = option(0.2, "how long a request waits for its answer, s", above=0.0,
                              maxval=10.0)


class ODriveBattery(Sensor):
    """Asks the ODrive (an RTR frame, CANSimple Get_Bus_Voltage_Current) for its DC bus voltage
    and current on a CAN socket of its own beside the wheel driver's. ``read`` gives
    ``voltage`` (V) and ``current`` (A, positive drawn from the battery)."""

    SETTINGS = ODriveBatterySettings

    def __init__(self, options: Any, *, section: str) -> None:
        super().__init__(options, section=section)
        self._bus: can.BusABC | None = None
        self._lock = threading.Lock()
        self.reads = 0

    def readings(self) -> tuple[str, ...]:
        return ("voltage", "current", "power")

    def where(self) -> str:
        s: ODriveBatterySettings = self.settings
        return f"ODrive node {s.node_id} on {s.interface}:{s.channel}"

    async def _open(self) -> None:
        s: ODriveBatterySettings = self.settings
        try:
            self._bus = await asyncio.to_thread(can.Bus, interface=s.interface,
                                                channel=s.channel)
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            raise DeviceError(f"[{self.section}] {self.where()}: cannot open the CAN bus "
                              f"({exc})") from None
        try:
            await self._read()  # an ODrive must answer before the battery counts as known
        except DeviceError:
            await self._close()
            raise

    async def _close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            await asyncio.to_thread(bus.shutdown)

    async def _read(self) -> dict[str, float]:
        try:
            volts, amps = await asyncio.to_thread(self._request)
        except DeviceError as exc:
            self.fault = str(exc)
            raise
        self.fault = None
        self.reads += 1
        return {"voltage": volts, "current": amps, "power": volts * amps}

    def _request(self) -> tuple[float, float]:
        s: ODriveBatterySettings = self.settings
        wanted = arbitration_id(s.node_id, CMD_GET_BUS_VOLTAGE_CURRENT)
        with self._lock:
            bus = self._bus
            if bus is None:
                raise DeviceError(f"[{self.section}] {self.where()}: not open")
            try:
                bus.send(can.Message(arbitration_id=wanted, is_remote_frame=True, dlc=8,
                                     is_extended_id=False), timeout=s.timeout_s)
                deadline = time.monotonic() + s.timeout_s
                while (left := deadline - time.monotonic()) > 0:
                    msg = bus.recv(left)
                    if msg is not None and msg.arbitration_id == wanted \
                            and not msg.is_remote_frame and not msg.is_extended_id:
                        return decode_bus_voltage_current(bytes(msg.data))
            except (can.CanError, OSError) as exc:
                raise DeviceError(f"[{self.section}] {self.where()}: {exc}") from None
            except FrameError as exc:
                raise DeviceError(f"[{self.section}] {self.where()}: a bad answer: "
                                  f"{exc}") from None
        raise DeviceError(f"[{self.section}] {self.where()}: no answer to "
                          f"Get_Bus_Voltage_Current within {s.timeout_s:g} s: is the ODrive "
                          "powered, on this bus, with this node id?")

    def _health(self) -> dict[str, Any]:
        return {"reads": self.reads}
