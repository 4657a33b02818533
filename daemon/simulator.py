# `arbiterd run --sim`: the world and the device emulators, wired to the daemon's real drivers.
from __future__ import annotations

import asyncio
import logging
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from aiohttp import web

from daemon.config import Config
from daemon.http_api import ApiError, HttpServer, json_response, read_json_object
from daemon.telemetry import OdomSample
from sim.motor_model import MotorPair, WheelMotor
from sim.settings import SimConfig
from sim.stepper import SimWorld
from sim.world import Pose

log = logging.getLogger("arbiterd.sim")

Stop = Callable[[], None]
# what an emulator starter returns: how to stop it, and [driver.<name>] options reaching it
Started = tuple[Stop, dict[str, Any]]

#: Encoder resolution of the emulated wheels per driver (edges are generated one by one for
#: pigpio, so it stays modest there).
COUNTS_PER_REV = {"mock": 1440, "serial": 1440, "pigpio": 200, "l298n": 200, "odrive_can": 8192}


class SimRuntime:
    """Owns the simulated world and the emulator of the chosen ``[sim] driver`` (component
    ``sim``). Built before the driver, so the driver connects to a running emulator."""

    name = "sim"
    core = True

    def __init__(self, config: Config) -> None:
        self.config = config
        self.sim = SimConfig.from_section(config["sim"])
        self.driver_name: str = config["sim"]["driver"]
        self.workdir = Path(tempfile.mkdtemp(prefix="arbiterd-sim-"))
        robot = config["robot"]
        self.motors = self._make_motors()
        self.world = SimWorld(self.sim, wheel_radius=robot["wheel_radius"],
                              wheel_separation=robot["wheel_separation"], motors=self.motors)
        self._stops: list[Stop] = []
        self._publisher: asyncio.Task[None] | None = None
        self.driver_options: dict[str, Any] = {}
        self.lidar_options: dict[str, Any] = {}

    def _make_motors(self) -> MotorPair:
        counts = COUNTS_PER_REV[self.driver_name]

        def wheel() -> WheelMotor:
            return WheelMotor(max_speed_rad_s=self.sim.motor_max_speed,
                              time_constant_s=self.sim.motor_time_constant,
                              counts_per_rev=counts)

        return MotorPair(wheel(), wheel(), clock=None)

    # -- wiring (before the daemon builds its driver) -------------------------------------

    def start_devices(self) -> None:
        """Start the world in real time and the emulators; fills the option overrides."""
        self.world.start()
        self._stops.append(self.world.close)
        stop, self.driver_options = EMULATORS[self.driver_name](self)
        self._stops.append(stop)
        if self.config["sim"]["lidar"]:
            self._start_lidar()
        log.info("simulated robot: %s emulator on %s", self.driver_name,
                 self.driver_options or "the mock driver")

    def _start_lidar(self) -> None:
        """An RPLIDAR A1 on a pty whose ranges are ray-cast from the world's true pose."""
        from sim.rplidar_emulator import A1, RplidarEmulator

        lidar = RplidarEmulator(self.workdir / "rplidar", A1, ranges_fn=self.world.scan_ranges,
                                rotation_hz=self.sim.lidar_rate,
                                seed=self.config["sim"]["seed"]).start()
        self._stops.append(lidar.close)
        self.lidar_options = {"enabled": True, "port": str(lidar.link),
                              "angle_bins": self.sim.lidar_rays,
                              "range_min": self.sim.range_min, "range_max": self.sim.range_max}

    def apply_to(self, config: Config) -> None:
        """Point the config's driver (and lidar) at the emulators."""
        config.sections["driver"]["type"] = self.driver_name
        config.sections[f"driver.{self.driver_name}"].update(self.driver_options)
        if self.lidar_options:
            config.sections["lidar"].update(self.lidar_options)

    def attach(self, driver: Any) -> None:
        """The mock driver has no wire: its commands turn the world's wheels directly."""
        if self.driver_name == "mock":
            driver.listeners.append(self.motors.set_targets)

    # -- component -----------------------------------------------------------------------

    def register(self, http: HttpServer, bus: Any, status_extras: dict[str, Any]) -> None:
        self.bus = bus
        http.add_route("POST", "/api/sim/reset", self._post_reset, access="drive")
        http.add_route("GET", "/api/sim/metrics", self._get_metrics, access="read")
        status_extras["ground_truth"] = lambda: self.world.ground_truth().to_json()

    async def start(self) -> None:
        self._publisher = asyncio.create_task(self._publish_ground_truth(), name="sim-truth")

    async def stop(self) -> None:
        if self._publisher:
            self._publisher.cancel()
        for stop in reversed(self._stops):
            try:
                stop()
            except Exception:
                log.exception("stopping a simulated device failed")

    def health(self) -> dict[str, Any]:
        return {**self.world.health(), "emulator": self.driver_name,
                "lidar": bool(self.lidar_options)}

    async def _publish_ground_truth(self) -> None:
        period = 1.0 / self.config["control"]["publish_rate"]
        robot = self.config["robot"]
        while True:
            truth = self.world.ground_truth()
            self.bus.publish("odom_ground_truth", OdomSample(
                time.time(), robot["odom_frame_id"], robot["base_frame_id"], truth.x, truth.y,
                truth.theta, truth.v, truth.w))
            await asyncio.sleep(period)

    async def _post_reset(self, request: web.Request) -> web.Response:
        body = await read_json_object(request, 4096) if request.can_read_body else {}
        pose = _parse_pose(body)
        truth = self.world.reset(pose)
        return json_response({"ground_truth": truth.to_json()})

    async def _get_metrics(self, request: web.Request) -> web.Response:
        return json_response(self.world.metrics_summary())


def _parse_pose(body: dict[str, Any]) -> Pose | None:
    unknown = sorted(set(body) - {"x", "y", "theta"})
    if unknown:
        raise ApiError(422, f"invalid pose: {unknown[0]}: unknown field")
    if not body:
        return None
    values = []
    for key in ("x", "y", "theta"):
        value = body.get(key, 0.0)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(
                value):
            raise ApiError(422, f"invalid pose: {key}: expected a finite number")
        values.append(float(value))
    return Pose(*values)


# -- one starter per [sim] driver ---------------------------------------------------------


def _start_mock(runtime: SimRuntime) -> Started:
    return (lambda: None), {}


def _start_serial(runtime: SimRuntime) -> Started:
    from sim.arduino_emulator import ArduinoEmulator

    board = ArduinoEmulator(runtime.workdir / "arduino", runtime.motors).start()
    return board.stop, {"port": str(board.link), "reset_wait_s": 0.05,
                        "counts_per_rev": COUNTS_PER_REV["serial"], "poll_rate": 50.0}


def _start_pigpio(runtime: SimRuntime) -> Started:
    from sim.pigpiod_emulator import PigpiodEmulator, pigpio_driver_wiring

    options = dict(runtime.config.driver_options("pigpio"))
    options.update(host="127.0.0.1", encoders=True, max_wheel_speed=runtime.sim.motor_max_speed,
                   encoder_counts_per_rev=COUNTS_PER_REV["pigpio"])
    pigpiod = PigpiodEmulator(pigpio_driver_wiring(options), runtime.motors, port=0).start()
    return pigpiod.close, {**{k: options[k] for k in ("host", "encoders", "max_wheel_speed",
                                                      "encoder_counts_per_rev")},
                           "port": pigpiod.port}


def _start_l298n(runtime: SimRuntime) -> Started:
    """gpiozero's PiGPIOFactory against the emulated pigpiod, L298N bridges on its pins."""
    from sim.pigpiod_emulator import PigpiodEmulator, l298n_driver_wiring

    options = dict(runtime.config.driver_options("l298n"))
    overrides = {"pin_factory": "pigpio", "pigpio_host": "127.0.0.1", "encoders": True,
                 "max_wheel_speed": runtime.sim.motor_max_speed,
                 "encoder_counts_per_rev": COUNTS_PER_REV["l298n"] // 4}  # quadrature cycles
    options.update(overrides)
    pigpiod = PigpiodEmulator(l298n_driver_wiring(options), runtime.motors, port=0).start()
    return pigpiod.close, {**overrides, "pigpio_port": pigpiod.port}


def _start_odrive(runtime: SimRuntime) -> Started:
    from sim.odrive_emulator import start_odrive_emulator

    options = runtime.config.driver_options("odrive_can")
    nodes = (options["left_node_id"], options["right_node_id"])
    channel = f"arbiterd-sim-{runtime.workdir.name}"
    directions = (-1 if options["left_inverted"] else 1, -1 if options["right_inverted"] else 1)
    odrive = start_odrive_emulator("virtual", channel, nodes, runtime.motors,
                                   directions=directions)
    return odrive.stop, {"interface": "virtual", "channel": channel}


EMULATORS: dict[str, Callable[[SimRuntime], Started]] = {
    "mock": _start_mock,
    "serial": _start_serial,
    "pigpio": _start_pigpio,
    "l298n": _start_l298n,
    "odrive_can": _start_odrive,
}
