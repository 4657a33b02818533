# The "battery" component: the monitor, /battery_state, GET /api/battery and the power policy.
from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

from aiohttp import web

from base.config import Config
from daemon.bus import BusKey
from daemon.commands import Twist
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, DeviceUse, Plugs, Route
from daemon.components.battery.charge import STATUS_CODES, ChargeEstimator, Reading
from daemon.components.battery.settings import DEVICES, BatterySettings
from daemon.health import Health
from daemon.messages.convert import header
from daemon.messages.definitions import BATTERY_STATE
from daemon.telemetry import POWER, PowerEvent
from daemon.topics import Topic, TopicOut
from daemon.web import json_response
from drivers.devices import DeviceError, Sensor, create_device

log = logging.getLogger("arbiterd.battery")

BATTERY: BusKey[Reading] = BusKey("battery_state")
SOURCE = "battery"
#: above every client and behaviour: at critical charge the wheels stop whoever drives
PRIORITY = 1000
#: reopening the monitor after a failed read or open: first and longest wait, s
RETRY_MIN_S, RETRY_MAX_S = 1.0, 30.0
#: BatteryState power_supply_technology: Li-ion
TECHNOLOGY_LION = 2

#: reads (volts, amps drawn) straight from a model (the simulator's pack)
ModelReader = Callable[[], tuple[float, float]]


def battery_state_msg(reading: Reading, capacity_ah: float = math.nan) -> dict[str, Any]:
    """sensor_msgs/msg/BatteryState of a reading (NaN: not measured, as the message says)."""
    return {"header": header(reading.stamp, "base_link"), "voltage": reading.voltage,
            "temperature": math.nan, "current": reading.current,
            "charge": reading.percentage * capacity_ah, "capacity": capacity_ah,
            "design_capacity": capacity_ah, "percentage": reading.percentage,
            "power_supply_status": STATUS_CODES[reading.status],
            "power_supply_health": 1, "power_supply_technology": TECHNOLOGY_LION,
            "present": True, "cell_voltage": [], "cell_temperature": [], "location": "",
            "serial_number": ""}


class BatteryComponent(BaseComponent):
    """Reads the monitor on the control tick's schedule, estimates the charge and runs the
    policy: ``low`` warns, ``very_low`` refuses new goals, missions and fetches (a gate of the
    navigation), ``critical`` holds the wheels at zero above every source, tells the recorder
    and the mapper (:data:`POWER`) and, after ``shutdown_delay_s`` off the charger, runs
    ``shutdown_command``. A reading it cannot trust is no reading: the last one is withdrawn
    and health says why."""

    name = "battery"
    core = False

    def __init__(self, settings: BatterySettings, plugs: Plugs, *,
                 make_device: Callable[[], Sensor] | None = None,
                 model: ModelReader | None = None,
                 wall_clock: Callable[[], float] = time.time) -> None:
        self.settings = settings
        self.make_device = make_device
        self.model = model
        self.device: Sensor | None = make_device() if make_device is not None else None
        self.robot = plugs.robot
        self.bus = plugs.bus
        self.plugs = plugs
        self.clock = self.robot.clock
        self.wall_clock = wall_clock
        self.estimator = ChargeEstimator(settings)
        self.latest: Reading | None = None
        #: why there is no trustworthy reading now (None: there is)
        self.problem: str | None = "not read yet"
        self.reads = self.failures = 0
        #: the policy's level: ok, low, very_low, critical
        self.level = "ok"
        self.critical_since: float | None = None
        self.shutdown_ran = False
        #: a component allowed to drive at very low charge (the dock going home)
        self.exempt: Callable[[], bool] = lambda: False
        self._retry_at = 0.0
        self._retry_s = RETRY_MIN_S
        self._inflight: asyncio.Task[None] | None = None
        self._tasks: set[asyncio.Task[Any]] = set()
        self._hold = plugs.while_busy(on_tick=self._hold_still)
        #: the wheels are held at zero (critical)
        self.holding = False
        plugs.schedule(self._due)

    # -- lifecycle ---------------------------------------------------------------------------

    async def start(self) -> None:
        if self.device is not None:
            await self._open()

    async def _open(self) -> bool:
        assert self.device is not None
        try:
            await self.device.open()
        except DeviceError as exc:
            self._failed(str(exc))
            return False
        log.info("battery: %s", getattr(self.device, "where", lambda: "monitor open")())
        return True

    def _failed(self, problem: str) -> None:
        if self.problem != problem:
            log.error("battery: %s", problem)
        self.problem, self.latest = problem, None
        self.failures += 1
        self._retry_at = self.clock() + self._retry_s
        self._retry_s = min(2 * self._retry_s, RETRY_MAX_S)

    async def stop(self) -> None:
        for task in (*self._tasks, *([self._inflight] if self._inflight else [])):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._hold.stop()
        self.robot.withdraw(SOURCE)
        if self.device is not None:
            await self.device.close()

    # -- reading -----------------------------------------------------------------------------

    def _due(self, now: float) -> float:
        if self.model is not None:
            self.take(now, *self.model())
        elif self._inflight is None or self._inflight.done():
            self._inflight = asyncio.get_running_loop().create_task(self._poll(now))
        return now + 1.0 / self.settings.rate

    async def _poll(self, now: float) -> None:
        device = self.device
        if device is None or self.make_device is None:
            return
        if not device.is_open:
            if now < self._retry_at:
                return
            if device.fault is not None or self.failures:
                await device.close()
                device = self.device = self.make_device()
            if not await self._open():
                return
        try:
            values = await device.read()
        except DeviceError as exc:
            self._failed(str(exc))
            await device.close()
            return
        self._retry_s = RETRY_MIN_S
        self.take(self.clock(), values["voltage"], values["current"])

    def take(self, now: float, volts: float, drawn_a: float) -> Reading | None:
        """One reading (V, A drawn from the pack): estimate, publish, apply the policy."""
        if not (math.isfinite(volts) and math.isfinite(drawn_a)):
            self._failed(f"the monitor gave a non-finite reading ({volts}, {drawn_a})")
            return None
        reading = self.estimator.update(now, volts, drawn_a)
        reading = Reading(self.wall_clock(), reading.voltage, reading.current,
                          reading.percentage, reading.status, reading.level)
        self.latest, self.problem = reading, None
        self.reads += 1
        self.bus.publish(BATTERY, reading)
        self._apply(now, reading)
        return reading

    # -- policy ------------------------------------------------------------------------------

    def _apply(self, now: float, reading: Reading) -> None:
        level = reading.level
        if level != self.level:
            self.level = level
            why = self.describe(reading)
            (log.warning if level != "ok" else log.info)("battery: %s", why)
            self.bus.publish(POWER, PowerEvent(reading.stamp, level, reading.percentage, why))
        if level == "critical":
            self._hold.start()
            self.holding = True
            charging = reading.status in ("charging", "full")
            if charging:
                self.critical_since = None
            elif self.critical_since is None:
                self.critical_since = now
            elif now - self.critical_since >= self.settings.shutdown_delay_s:
                self._shutdown()
        else:
            self.critical_since = None
            if self.holding:
                self._hold.stop()
                self.holding = False
                self.robot.withdraw(SOURCE)

    def _hold_still(self, now: float, on_time: bool) -> None:
        self.robot.propose(SOURCE, Twist(0.0, 0.0), now, PRIORITY)

    def describe(self, reading: Reading) -> str:
        s = self.settings
        pct = f"{reading.percentage * 100:.0f} %"
        return {
            "ok": f"charge {pct}",
            "low": f"battery low: {pct} (below {s.low * 100:g} %): going home when the "
                   "current task ends",
            "very_low": f"battery very low: {pct} (below {s.very_low * 100:g} %): new goals, "
                        "missions and fetches are refused until it charges",
            "critical": f"battery critical: {pct} (below {s.critical * 100:g} %): the motors "
                        "are stopped, the recording closed and the map saved",
        }[reading.level]

    def refusal(self) -> str | None:
        """The navigation's gate: why no new goal may start now."""
        reading = self.latest
        if reading is None or self.level not in ("very_low", "critical") or self.exempt():
            return None
        return self.describe(reading)

    def _shutdown(self) -> None:
        command = self.settings.shutdown_command
        if self.shutdown_ran or not command:
            return
        self.shutdown_ran = True
        log.critical("battery: critical for %g s off the charger: running %s",
                     self.settings.shutdown_delay_s, " ".join(command))
        task = asyncio.get_running_loop().create_task(self._run_shutdown(command))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _run_shutdown(self, command: list[str]) -> None:
        try:
            process = await asyncio.create_subprocess_exec(*command)
            code = await process.wait()
            log.info("battery: %s exited with %d", command[0], code)
        except OSError as exc:
            log.error("battery: cannot run %s: %s", command[0], exc)

    # -- reports -----------------------------------------------------------------------------

    def state(self) -> dict[str, Any]:
        reading = self.latest
        body: dict[str, Any] = {"voltage": None, "current": None, "percentage": None,
                                "status": "unknown", "level": self.level,
                                "problem": self.problem}
        if reading is not None:
            body.update(reading.to_json())
        body["thresholds"] = {"low": self.settings.low, "very_low": self.settings.very_low,
                              "critical": self.settings.critical}
        body["device"] = self.settings.device
        return body

    def health(self) -> Health:
        values = {k: v for k, v in self.state().items()
                  if k not in ("thresholds", "problem", "status")}
        values["power_supply_status"] = self.state()["status"]
        values.update({"reads": self.reads, "failures": self.failures})
        if self.device is not None:
            values["monitor"] = {k: v for k, v in self.device.health().items()
                                 if isinstance(v, int | float) and not isinstance(v, bool)}
        if self.problem is not None:
            return Health("error", self.problem, values)
        reading = self.latest
        assert reading is not None
        if self.level == "critical":
            return Health("error", self.describe(reading), values)
        if self.level != "ok":
            return Health("degraded", self.describe(reading), values)
        return Health("ok", values=values)

    def routes(self) -> Sequence[Route]:
        return (Route("GET", "/api/battery", self.get_battery, "read"),)

    async def get_battery(self, request: web.Request) -> web.Response:
        return json_response(self.state())

    def topics(self) -> Sequence[Topic]:
        capacity = self.settings.capacity_ah
        return (TopicOut("/battery_state", BATTERY_STATE, BATTERY,
                         lambda r: battery_state_msg(r, capacity),
                         f"{self.settings.rate:g} Hz"),)


def build_monitor(config: Config) -> Sensor:
    """The [battery] section's monitor device (built, not opened)."""
    settings = config.get(BatterySettings)
    device = create_device(DEVICES[settings.device], config["battery"], section="battery")
    assert isinstance(device, Sensor)
    return device


def create(ctx: DaemonContext) -> BatteryComponent | None:
    settings = ctx.settings(BatterySettings)
    if not settings.enabled:
        return None
    problems = settings.problems()
    if problems:
        raise ValueError(problems[0])
    if settings.device == "sim":
        if ctx.sim is None:
            raise ValueError("[battery] device = sim needs the simulator (arbiterd run --sim)")
        pack = ctx.sim.world.battery
        component = BatteryComponent(settings, ctx.plugs, model=pack.measure)
    else:
        config = ctx.config
        component = BatteryComponent(settings, ctx.plugs,
                                     make_device=lambda: build_monitor(config))
    nav = ctx.components.get("navigation")
    gates = getattr(nav, "gates", None)
    if isinstance(gates, list):
        gates.append(component.refusal)
        ctx.plugs.add(lambda: gates.remove(component.refusal))
    return component


def devices(config: Config) -> list[DeviceUse]:
    settings = config.get(BatterySettings)
    if not settings.enabled or settings.device == "sim":
        return []
    return [DeviceUse(DEVICES[settings.device], "battery")]


COMPONENT = ComponentSpec("battery", create, BatterySettings, devices)
