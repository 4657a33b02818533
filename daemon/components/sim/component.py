# `arbiterd run --sim`: the world and the device emulators, wired to the daemon's real drivers.
from __future__ import annotations

import asyncio
import logging
import shutil
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from aiohttp import web

from base.config import Config
from daemon import coords
from daemon.commands import CommandError, parse_pose
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, DeviceUse, Route
from daemon.coords import CoordinateError, Extent
from daemon.health import Health
from daemon.messages.convert import odometry_msg
from daemon.messages.definitions import ODOMETRY
from daemon.robot import RobotBase
from daemon.settings import ControlSettings, RobotSettings
from daemon.telemetry import ODOM_GROUND_TRUTH, OdomSample
from daemon.topics import Topic, TopicOut
from daemon.web import ApiError, json_response, read_json_object
from sim.motor_model import MotorPair
from sim.settings import SimConfig, SimSettings
from sim.stepper import SimWorld
from sim.wiring import DEVICE_EMULATORS, EMULATORS
from sim.world import Pose
from slam.pose import Pose2, between, compose, inverse

log = logging.getLogger("arbiterd.sim")


class SimRuntime(BaseComponent):
    """Owns the simulated world and the emulator of the chosen ``[sim] driver`` (component
    ``sim``). Built before the driver, so the driver connects to a running emulator."""

    name = "sim"
    core = True

    def __init__(self, config: Config, devices: Sequence[DeviceUse] = ()) -> None:
        self.config = config
        #: the devices (beside the wheels and the lidar) whose emulators it starts
        self.devices = list(devices)
        #: section => the options reaching each device's emulator
        self.device_options: dict[str, dict[str, Any]] = {}
        #: section => the running emulator of its device (tests look at its state)
        self.device_emulators: dict[str, Any] = {}
        self.settings = config.get(SimSettings)
        self.sim = SimConfig.from_settings(config.get(SimSettings))
        self.driver_name: str = self.settings.driver
        self.workdir = Path(tempfile.mkdtemp(prefix="arbiterd-sim-"))
        robot = config.get(RobotSettings)
        self.motors = self._make_motors()
        self.world = SimWorld(self.sim, wheel_radius=robot.wheel_radius,
                              wheel_separation=robot.wheel_separation, motors=self.motors)
        self.bus: Any = None
        #: the control loop, once the daemon built it (a reset puts odometry on the new pose)
        self.robot: RobotBase | None = None
        self._stops: list[Callable[[], None]] = []
        self._publisher: asyncio.Task[None] | None = None
        #: the world pose odometry started from (its integrated frame's origin)
        self._anchor: Pose2 = (0.0, 0.0, 0.0)
        self.driver_options: dict[str, Any] = {}
        self.lidar_options: dict[str, Any] = {}

    def _make_motors(self) -> MotorPair:
        return EMULATORS[self.driver_name].motors(max_speed_rad_s=self.sim.motor_max_speed,
                                                  time_constant_s=self.sim.motor_time_constant,
                                                  clock=None)

    # -- wiring (before the daemon builds its driver) -------------------------------------

    def start_devices(self) -> None:
        """Start the world in real time and the emulators; fills the option overrides."""
        self.world.start()
        self._stops.append(self.world.close)
        emulated = EMULATORS[self.driver_name].start(
            self.motors, self.workdir, self.config.driver_options(self.driver_name),
            self.sim.miswire)
        self._stops.append(emulated.stop)
        self.driver_options = emulated.options
        if self.settings.lidar:
            self._start_lidar()
        for use in self.devices:
            self._start_device(use)
        log.info("simulated robot: %s emulator on %s", self.driver_name,
                 self.driver_options or "the mock driver")

    def _start_lidar(self) -> None:
        """An RPLIDAR A1 on a pty whose ranges are ray-cast from the world's true pose."""
        from sim.rplidar_emulator import A1, RplidarEmulator

        lidar = RplidarEmulator(self.workdir / "rplidar", A1, ranges_fn=self.world.scan_ranges,
                                rotation_hz=self.sim.lidar_rate,
                                seed=self.settings.seed).start()
        self._stops.append(lidar.close)
        self.lidar_options = {"enabled": True, "port": str(lidar.link),
                              "angle_bins": self.sim.lidar_rays,
                              "range_min": self.sim.range_min, "range_max": self.sim.range_max}

    def _start_device(self, use: DeviceUse) -> None:
        starter = DEVICE_EMULATORS.get(use.device)
        if starter is None:
            raise ValueError(f"[{use.section}] device {use.device!r} has no emulator in "
                             "sim/wiring.py DEVICE_EMULATORS")
        workdir = self.workdir / use.section
        workdir.mkdir(exist_ok=True)
        emulated = starter(workdir, self.config[use.section])
        self._stops.append(emulated.stop)
        use_battery = getattr(emulated.emulator, "use_battery", None)
        if use_battery is not None:  # a battery monitor measures the world's pack
            use_battery(self.world.battery)
        self.device_options[use.section] = emulated.options
        self.device_emulators[use.section] = emulated.emulator
        log.info("simulated device: %s for [%s] on %s", use.device, use.section,
                 emulated.options)

    def apply_to(self, config: Config) -> None:
        """Point the config's driver (and lidar) at the emulators."""
        config.update("driver", {"type": self.driver_name})
        config.update(f"driver.{self.driver_name}", self.driver_options)
        if self.lidar_options:
            config.update("lidar", self.lidar_options)
        for section, options in self.device_options.items():
            config.update(section, options)

    def attach(self, driver: Any) -> None:
        """The mock driver has no wire: its commands turn the world's wheels directly, and its
        encoders read them (so odometry counts the wheels' true turns, as with the emulated
        boards, also when the world's thread falls behind and skips ahead)."""
        if self.driver_name == "mock":
            driver.listeners.append(self.motors.set_targets)
            driver.encoder_source = self.motors.encoder_positions

    # -- component -----------------------------------------------------------------------

    def routes(self) -> Sequence[Route]:
        return (Route("POST", "/api/sim/reset", self._post_reset, "drive"),
                Route("GET", "/api/sim/metrics", self._get_metrics, "read"),
                Route("GET", "/api/sim/objects", self._get_objects, "read"),
                Route("POST", "/api/sim/objects", self._post_objects, "drive"),
                Route("DELETE", "/api/sim/objects", self._delete_objects, "drive"))

    def topics(self) -> Sequence[Topic]:
        return (TopicOut("/odom_ground_truth", ODOMETRY, ODOM_GROUND_TRUTH, odometry_msg,
                         "20 Hz"),)

    async def start(self) -> None:
        truth = self.world.ground_truth()
        self._anchor = (truth.x, truth.y, truth.theta)  # odometry starts here, at zero
        self._publisher = asyncio.create_task(self._publish_ground_truth(), name="sim-truth")

    async def stop(self) -> None:
        if self._publisher:
            self._publisher.cancel()
        for stop in reversed(self._stops):
            try:
                stop()
            except Exception:
                log.exception("stopping a simulated device failed")
        shutil.rmtree(self.workdir, ignore_errors=True)

    def health(self) -> Health:
        return Health.of({**self.world.health(), "emulator": self.driver_name,
                          "lidar": bool(self.lidar_options)}, "error")

    async def _publish_ground_truth(self) -> None:
        period = 1.0 / self.config.get(ControlSettings).publish_rate
        robot = self.config.get(RobotSettings)
        while True:
            truth = self.world.ground_truth()
            x, y, theta = self.truth_in_odom((truth.x, truth.y, truth.theta))
            self.bus.publish(ODOM_GROUND_TRUTH, OdomSample(
                time.time(), robot.odom_frame_id, robot.base_frame_id, x, y, theta, truth.v,
                truth.w))
            await asyncio.sleep(period)

    def truth_in_odom(self, truth: Pose2) -> Pose2:
        """The world pose ``truth`` in the odometry frame ``/odom`` reports in: the world seen
        from where odometry started (``_anchor``), moved as odometry resets moved the reported
        frame (reported ∘ integrated⁻¹). Drawn beside ``/odom``, the gap is the drift."""
        start_frame = between(self._anchor, truth)
        if self.robot is None:
            return start_frame
        reported, integrated = self.robot.pose(), self.robot.integrated_pose()
        moved = compose((reported.x, reported.y, reported.theta),
                        inverse((integrated.x, integrated.y, integrated.theta)))
        return compose(moved, start_frame)

    def _extent(self) -> Extent:
        """The simulated world's walls (what a teleport or an object must be within)."""
        walls = self.world.world.segment_array
        xs, ys = walls[:, [0, 2]], walls[:, [1, 3]]
        return Extent(float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max()),
                      "the simulated world") if walls.size else Extent(0.0, 0.0, 0.0, 0.0)

    async def _post_reset(self, request: web.Request) -> web.Response:
        """Teleport, and let odometry report the new pose, so the two start together again."""
        body = await read_json_object(request, 4096) if request.can_read_body else {}
        try:
            values = parse_pose(body)
            if values is not None:
                self._extent().check(values[0], values[1], "x, y")
        except (CommandError, CoordinateError) as exc:
            raise ApiError(422, f"invalid pose: {exc}") from None
        try:
            truth = self.world.reset(Pose(*values) if values else None)
        except ValueError as exc:  # not finite, or the footprint on an obstacle
            raise ApiError(400, f"cannot place the robot there: {exc}") from None
        if self.robot is not None:  # a teleport: odometry's start moves with the robot
            integrated = self.robot.integrated_pose()
            self._anchor = compose((truth.x, truth.y, truth.theta),
                                   inverse((integrated.x, integrated.y, integrated.theta)))
            self.robot.reset_odometry(truth.x, truth.y, truth.theta,
                                        by=f"HTTP {request.remote or '?'} (sim reset)")
        return json_response({"ground_truth": truth.to_json()})

    async def _get_objects(self, request: web.Request) -> web.Response:
        return json_response({"objects": self.world.objects_report()})

    async def _post_objects(self, request: web.Request) -> web.Response:
        """Place a graspable object (sim/objects.py) at ``{"x", "y"}`` in the world's frame."""
        body = await read_json_object(request, 4096)
        unknown = sorted(set(body) - {"x", "y"})
        if unknown:
            raise ApiError(422, f"{unknown[0]}: unknown field (x, y)")
        try:
            point = coords.point([body.get("x"), body.get("y")], ("x", "y"), self._extent())
        except CoordinateError as exc:
            raise ApiError(422, str(exc)) from None
        try:
            self.world.place_object(point[0], point[1])
        except ValueError as exc:
            raise ApiError(409, f"cannot place an object there: {exc}") from None
        return json_response({"objects": self.world.objects_report()})

    async def _delete_objects(self, request: web.Request) -> web.Response:
        self.world.clear_objects()
        return json_response({"objects": []})

    async def _get_metrics(self, request: web.Request) -> web.Response:
        return json_response(self.world.metrics_summary())


def create(ctx: DaemonContext) -> SimRuntime | None:
    """The simulated world of ``run --sim`` (built before the driver; see :class:`SimRuntime`)."""
    runtime = ctx.sim
    if runtime is None:
        return None
    if not isinstance(runtime, SimRuntime):
        raise TypeError(f"ctx.sim is a {type(runtime).__name__}, not the SimRuntime it built")
    runtime.bus = ctx.bus
    runtime.robot = ctx.robot
    ctx.plugs.add_status("ground_truth", lambda: runtime.world.ground_truth().to_json())
    return runtime


COMPONENT = ComponentSpec("sim", create, SimSettings)
