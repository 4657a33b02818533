# SimWorld: world, physics, motors, lidar, noise and metrics behind one fixed-rate stepper.
from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim.battery import BatteryModel, BatterySpec
from sim.metrics import RunMetrics
from sim.motor_model import MotorPair
from sim.noise import Noise
from sim.objects import Objects, ToolReader, cast_circles
from sim.physics import DiffDrivePhysics, RobotGeometry, make_motors
from sim.raycast import RayCaster, ray_angles
from sim.settings import SimConfig, SimConfigError
from sim.world import Pose, World, generated_world, load_world

log = logging.getLogger(__name__)

#: Fall this far behind real time (s) and the real-time runner skips ahead instead of racing.
MAX_LAG_S = 0.5


@dataclass(frozen=True)
class GroundTruth:
    """The robot's true state at simulated time ``t`` (s since the world was built)."""

    t: float
    x: float
    y: float
    theta: float
    v: float
    w: float
    collisions: int
    in_contact: bool

    def to_json(self) -> dict[str, Any]:
        return {"t": round(self.t, 6), "x": self.x, "y": self.y, "theta": self.theta,
                "v": self.v, "w": self.w, "collisions": self.collisions,
                "in_contact": self.in_contact}


def build_world(config: SimConfig) -> World:
    """The world the settings describe: the world file, or the seeded arena."""
    if config.world_file:
        return load_world(config.world_file)
    return generated_world(config.seed, size=config.arena_size, obstacles=config.obstacles,
                           radius_min=config.obstacle_radius_min,
                           radius_max=config.obstacle_radius_max, start=config.start_pose,
                           start_clearance=config.start_clearance)


class SimWorld:
    """The simulated robot in its world, stepped at ``physics_rate``.

    Step it yourself (:meth:`step`, :meth:`advance`) for exact, reproducible runs faster than
    real time, or :meth:`start` a thread that steps it in real time for the daemon. The
    emulators share :attr:`motors` (a :class:`MotorPair` with ``clock=None``): they command
    and read it, the world advances it. ``wheel_sign`` is -1 when the emulated hardware turns
    the wheels backwards to drive forwards. ``wheel_radius`` and ``wheel_separation`` are
    the configured ones (:attr:`configured`); the physics moves the robot with the true ones
    (:attr:`geometry`: off by ``[sim] wheel_radius_error`` / ``wheel_separation_error``), and
    the encoders count true wheel turns, so odometry made with the configured geometry drifts
    as on a miscalibrated base. With ``internal_scans`` the world also casts a
    full scan at ``lidar_rate`` into :attr:`latest_scan` (tests and benchmarks; the daemon's
    lidar asks :meth:`scan_ranges` instead). Every public method is thread-safe.
    """

    def __init__(self, config: SimConfig | None = None, *, wheel_radius: float = 0.05,
                 wheel_separation: float = 0.30, motors: MotorPair | None = None,
                 world: World | None = None, wheel_sign: int = 1,
                 internal_scans: bool = False) -> None:
        self.config = config or SimConfig.from_section()
        if motors is not None and getattr(motors, "_clock", None) is not None:
            raise ValueError("the world steps the motors: pass a MotorPair made with clock=None")
        self.world = world or build_world(self.config)
        self.motors = motors or make_motors(self.config.motor_max_speed,
                                            self.config.motor_time_constant)
        #: the geometry the daemon is configured with ([robot]); :attr:`geometry` is the truth
        self.configured = RobotGeometry(wheel_radius, wheel_separation,
                                        self.config.footprint_radius)
        self.geometry = RobotGeometry(*self.config.true_geometry(wheel_radius, wheel_separation),
                                      self.config.footprint_radius)
        self.noise = Noise(self.config.noise)
        self.physics = DiffDrivePhysics(self.world, self.motors, self.geometry, self.noise,
                                        wheel_sign=wheel_sign)
        self.lidar = RayCaster(self.world, ray_angles(self.config.lidar_rays),
                               self.config.range_min, self.config.range_max)
        self.metrics = _open_metrics(self.config)
        self.internal_scans = internal_scans
        self.latest_scan: np.ndarray | None = None
        self.latest_scan_time = 0.0
        #: the pack the motors and the computer draw from, charged while :attr:`on_charger`
        self.battery = BatteryModel(BatterySpec(capacity_ah=self.config.battery_capacity_ah,
                                                drain=self.config.battery_drain),
                                    soc=self.config.battery_charge)
        #: whether the robot's contacts touch a charging dock now (the world's docks)
        self.on_charger: Callable[[], bool] = self._on_dock
        #: graspable objects (sim/objects.py), moved by :attr:`arm_tool` when an arm is on
        self.objects = Objects()
        #: where the arm's tool point is (set by whoever runs the arm), else None
        self.arm_tool: ToolReader | None = None
        self.steps = 0
        self.overruns = 0
        self.error: str | None = None
        self._dt = self.config.physics_dt
        self._next_scan = 0.0
        self._device_caster: RayCaster | None = None
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @classmethod
    def from_sections(cls, sim: Mapping[str, Any], robot: Mapping[str, Any] | None = None,
                      **kwargs: Any) -> SimWorld:
        """Build from the daemon's ``[sim]`` and ``[robot]`` sections (the physical wheel
        radius and separation; calibration multipliers are the daemon's business)."""
        robot = robot or {}
        return cls(SimConfig.from_section(sim), wheel_radius=robot.get("wheel_radius", 0.05),
                   wheel_separation=robot.get("wheel_separation", 0.30), **kwargs)

    # -- stepping -------------------------------------------------------------------------

    @property
    def time(self) -> float:
        """Simulated seconds since the world was built."""
        return self.steps * self._dt

    def step(self) -> None:
        """One physics step of ``1/physics_rate`` seconds (and a scan when one is due)."""
        with self._cond:
            self.physics.step(self._dt)
            self.steps += 1
            state = self.physics.state
            if self.objects.items:
                self.objects.update(state.x, state.y, state.theta,
                                    self.arm_tool() if self.arm_tool else None,
                                    self.geometry.footprint_radius)
            self.battery.step(self._dt, self.motors.speeds(), self.on_charger())
            self.metrics.record(self._dt, state.x, state.y, state.theta, state.v, state.w,
                                state.travelled, state.collisions)
            if self.internal_scans and self.time + 1e-9 >= self._next_scan:
                self.latest_scan = self.noise.lidar(self._with_objects(
                    self.lidar, self.lidar.cast(state.x, state.y, state.theta),
                    (state.x, state.y, state.theta)))
                self.latest_scan_time = self.time
                self._next_scan = self.time + 1.0 / self.config.lidar_rate
            self._cond.notify_all()

    def _on_dock(self) -> bool:
        if not self.world.docks:
            return False
        state = self.physics.state
        return self.world.docked(state.x, state.y, state.theta)

    def advance(self, seconds: float) -> None:
        """Step ``round(seconds * physics_rate)`` times, as fast as possible."""
        for _ in range(round(seconds * self.config.physics_rate)):
            self.step()

    def command_twist(self, v: float, w: float) -> None:
        """Set the wheel motors' targets for a body twist with the configured geometry, as a
        driver would (tests and benchmarks; the daemon commands the motors through a driver
        and an emulator instead)."""
        half = w * self.configured.wheel_separation / 2.0
        sign, radius = self.physics.wheel_sign, self.configured.wheel_radius
        self.motors.set_targets(sign * (v - half) / radius, sign * (v + half) / radius)

    # -- real time ------------------------------------------------------------------------

    def start(self, speed: float = 1.0) -> None:
        """Step on a background thread at ``speed`` x real time (1.0 for the daemon)."""
        if speed <= 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        if self._thread is not None and self._thread.is_alive():
            raise RuntimeError("the simulated world is already running")
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, args=(speed,), name="sim-world",
                                        daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def stop(self) -> None:
        """Stop the real-time thread (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def close(self) -> None:
        """Stop stepping and close the metrics CSV."""
        self.stop()
        with self._cond:
            self.metrics.close()

    def _run(self, speed: float) -> None:
        period = self._dt / speed
        deadline = time.monotonic()
        try:
            while not self._stop.is_set():
                self.step()
                deadline += period
                delay = deadline - time.monotonic()
                if delay > 0:
                    self._stop.wait(delay)
                elif delay < -MAX_LAG_S:
                    self.overruns += 1
                    deadline = time.monotonic()
        except Exception as exc:  # reported in health(); the daemon keeps running
            log.exception("simulated world stopped")
            self.error = f"world step failed: {exc}"

    def wait_until(self, sim_time: float, timeout: float) -> bool:
        """Block until simulated time reaches ``sim_time``; False after ``timeout`` real s."""
        with self._cond:
            return self._cond.wait_for(lambda: self.time + 1e-9 >= sim_time, timeout)

    # -- what the daemon and the emulators read -------------------------------------------

    def ground_truth(self) -> GroundTruth:
        with self._cond:
            s = self.physics.state
            return GroundTruth(self.time, s.x, s.y, s.theta, s.v, s.w, s.collisions,
                               s.in_contact)

    def scan_ranges(self, angles_rad: np.ndarray, t: float) -> np.ndarray:
        """Ranges (m, ``inf`` = no return) at the lidar's own angles, for the RPLIDAR emulator.

        ``angles_rad`` follow the RPLIDAR convention: clockwise from straight ahead, seen from
        above. ``t`` is accepted for the emulator's signature; the pose used is the current
        one (the world runs in real time beside the emulator). Noise is added when enabled.
        """
        del t
        angles = np.asarray(angles_rad, dtype=float)
        caster = self._device_caster
        if caster is None or not np.array_equal(caster.angles, -angles):
            caster = self.lidar.with_angles(-angles)
            self._device_caster = caster
        pose = self._pose()
        return self.noise.lidar(self._with_objects(caster, caster.cast(*pose), pose))

    def scan(self) -> np.ndarray:
        """A full scan now: ``lidar_rays`` ranges counter-clockwise from straight ahead
        (the ROS LaserScan convention), with noise when enabled."""
        pose = self._pose()
        return self.noise.lidar(self._with_objects(self.lidar, self.lidar.cast(*pose), pose))

    def _with_objects(self, caster: RayCaster, ranges: np.ndarray,
                      pose: tuple[float, float, float]) -> np.ndarray:
        """The objects standing on the floor are seen too (a held one is lifted off it)."""
        if not self.objects.items:
            return ranges
        with self._cond:
            circles = self.objects.circles()
        return cast_circles(ranges, circles, *pose, caster.angles, caster.range_max)

    def exact_range(self, angle_ccw: float) -> float:
        """The noise-free ray-cast distance along one angle (rad, counter-clockwise)."""
        caster = RayCaster(self.world, np.array([angle_ccw]), self.config.range_min,
                           self.config.range_max)
        return float(caster.cast(*self._pose())[0])

    def _pose(self) -> tuple[float, float, float]:
        with self._cond:
            s = self.physics.state
            return s.x, s.y, s.theta

    def place_object(self, x: float, y: float, color: str = "red") -> None:
        """A graspable object standing at (x, y); ValueError when it would stand inside a
        wall or an obstacle, or under the robot, or has an unknown colour."""
        with self._cond:
            radius = self.objects.place(x, y, color=color).radius  # checks it is finite
            self.objects.items.pop()
            if self.world.clearance(x, y) < radius:
                raise ValueError(f"({x}, {y}) is inside a wall or an obstacle")
            state = self.physics.state
            if math.hypot(x - state.x, y - state.y) < self.geometry.footprint_radius + radius:
                raise ValueError(f"({x}, {y}) is under the robot")
            self.objects.place(x, y, color=color)

    def camera_view(self) -> tuple[tuple[float, float, float], list[tuple[float, float, float,
                                                                             str]]]:
        """The true pose and the standing objects at one instant, for the simulated camera."""
        with self._cond:
            s = self.physics.state
            return (s.x, s.y, s.theta), self.objects.standing()

    def clear_objects(self) -> None:
        with self._cond:
            self.objects.clear()

    def objects_report(self) -> list[dict[str, Any]]:
        with self._cond:
            return self.objects.report()

    def reset(self, pose: Pose | None = None) -> GroundTruth:
        """Teleport the robot (default: the world's start pose) and start a new metrics run.

        Raises ``ValueError`` naming the problem when the pose is not finite or puts the
        footprint on an obstacle. The motors are left as they are (the driver owns them).
        """
        target = pose or self.world.start
        with self._cond:
            self.physics.place(target)
            self.metrics.reset()
            self.latest_scan = None
        return self.ground_truth()

    def metrics_summary(self) -> dict[str, Any]:
        """The current run's metrics, for ``GET /api/sim/metrics``."""
        with self._cond:
            return {**self.metrics.summary(), "sim_time_s": round(self.time, 6)}

    def health(self) -> dict[str, Any]:
        """State for ``/api/health`` (status error when the real-time thread died)."""
        with self._cond:
            state = self.physics.state
            return {
                "status": "error" if self.error else "ok",
                "error": self.error,
                "running": self.running,
                "sim_time_s": round(self.time, 3),
                "overruns": self.overruns,
                "collisions": state.collisions,
                "noise": self.config.noise.enabled,
                "obstacles": len(self.world.circles),
                "walls": len(self.world.segments),
            }


def _open_metrics(config: SimConfig) -> RunMetrics:
    try:
        return RunMetrics(config.metrics_csv or None, config.metrics_rate)
    except OSError as exc:
        raise SimConfigError(f"[sim] metrics_csv: cannot write {config.metrics_csv!r}: "
                             f"{exc.strerror or exc}") from None


def heading_error(a: float, b: float) -> float:
    """Smallest absolute difference between two headings (rad)."""
    return abs(math.atan2(math.sin(a - b), math.cos(a - b)))
