# The [sim] config section: its keys, declared once, and the validated simulator settings.
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

from base.config import SectionSettings
from base.options import defaults, option
from drivers.registry import DRIVERS
from sim.motor_model import MISWIRES
from sim.noise import NoiseConfig
from sim.world import Pose, WorldError, builtin_worlds, world_path


def world_file_error(value: str) -> str | None:
    """Why ``[sim] world_file`` names no world (a file is only read when the world is built)."""
    try:
        if value:
            world_path(value)
    except WorldError as exc:
        return str(exc)
    return None


@dataclass(frozen=True)
class SimSettings(SectionSettings, section="sim"):
    """The [sim] section, read once: every [sim] key, its default, doc and bounds."""

    driver: str = option("serial", "which emulator --sim wires to the real driver",
                         choices=tuple(DRIVERS))
    seed: int = option(1, "seed of the obstacle placement and of every noise stream", minval=0)
    world_file: str = option("", "world file (.toml or .json) to load, or the name of a built-in "
                             f"world ({', '.join(builtin_worlds())}); '' = generated arena",
                             check=world_file_error)
    arena_size: float = option(16.0, "side of the generated square arena (m)", above=2.0,
                               maxval=1000.0)
    obstacles: int = option(8, "number of circular obstacles in the generated arena", minval=0,
                            maxval=200)
    obstacle_radius_min: float = option(0.3, "smallest generated obstacle radius (m)", above=0.0)
    obstacle_radius_max: float = option(0.6, "largest generated obstacle radius (m)", above=0.0)
    start_clearance: float = option(1.5, "no generated obstacle within this distance of the start "
                                    "position (m)", minval=0.0)
    start_pose: list[float] = option([0.0, 0.0, 0.0], "start pose [x m, y m, theta rad] of the "
                                     "generated arena", length=3)
    footprint_radius: float = option(0.2, "radius of the robot's round footprint (m)", above=0.0)
    physics_rate: float = option(50.0, "physics steps per second of simulated time", minval=10.0,
                                 maxval=2000.0)
    lidar_rate: float = option(10.0, "lidar revolutions per second", minval=1.0, maxval=50.0)
    lidar_rays: int = option(360, "rays per lidar revolution", minval=8, maxval=8192)
    range_min: float = option(0.1, "nearest lidar return (m)", minval=0.0)
    range_max: float = option(10.0, "farthest lidar return (m)", above=0.0)
    noise: bool = option(True, "inject noise and slip (false: exact runs)")
    lidar_noise: float = option(0.02, "Gaussian lidar range noise sigma (m)", minval=0.0)
    odom_noise: float = option(0.005, "Gaussian encoder noise sigma per step (m)", minval=0.0)
    wheel_slip: float = option(0.0, "fraction of wheel travel lost at the ground", minval=0.0,
                               below=1.0)
    lidar_dropout: float = option(0.0, "fraction of lidar returns that go missing (seeded)",
                                  minval=0.0, below=1.0)
    wheel_radius_error: float = option(0.0, "calibration error: the true wheel radius is [robot] "
                                       "wheel_radius x (1 + this)", minval=-0.5, maxval=0.5)
    wheel_separation_error: float = option(0.0, "calibration error: the true wheel separation is "
                                           "[robot] wheel_separation x (1 + this)", minval=-0.5,
                                           maxval=0.5)
    motor_time_constant: float = option(0.05, "first-order wheel motor time constant (s)",
                                        minval=0.0, maxval=5.0)
    motor_max_speed: float = option(40.0, "wheel motor saturation speed (rad/s)", above=0.0)
    metrics_csv: str = option("", "stream run metrics to this CSV file ('' = off)")
    metrics_rate: float = option(10.0, "metrics CSV rows per second of simulated time", above=0.0,
                                 maxval=1000.0)
    lidar: bool = option(True, "emulate an RPLIDAR A1 (on a pty) whose ranges come from the "
                         "world, and read it through the real lidar manager")
    battery_capacity_ah: float = option(2.6, "the simulated pack's capacity (3 Li-ion cells "
                                        "in series), Ah", above=0.0, maxval=1000.0)
    battery_charge: float = option(1.0, "the simulated pack's charge at the start, 0..1",
                                   minval=0.0, maxval=1.0)
    battery_drain: float = option(1.0, "multiplies every load on the simulated pack (100: "
                                  "drain it a hundred times faster to watch the robot go home)",
                                  minval=0.0, maxval=100000.0)
    miswire: list[str] = option([], "wiring faults the emulated motors and encoders play "
                                f"(bring-up tests): {', '.join(MISWIRES)}", choices=MISWIRES)


class SimConfigError(ValueError):
    """A [sim] setting that is invalid on its own or together with another key."""


@dataclass(frozen=True)
class SimConfig:
    """Validated [sim] settings, ready for :class:`sim.stepper.SimWorld`: the keys of
    :class:`SimSettings` (their defaults and bounds are declared there, once), with the start
    pose as a :class:`Pose`, the noise keys as a :class:`NoiseConfig` and the miswires as a
    tuple. Made by :meth:`from_section` (``SimConfig.from_section()``: every default) or
    :meth:`from_settings`."""

    driver: str
    seed: int
    world_file: str
    arena_size: float
    obstacles: int
    obstacle_radius_min: float
    obstacle_radius_max: float
    start_clearance: float
    start_pose: Pose
    footprint_radius: float
    physics_rate: float
    lidar_rate: float
    lidar_rays: int
    range_min: float
    range_max: float
    noise: NoiseConfig
    wheel_radius_error: float
    wheel_separation_error: float
    motor_time_constant: float
    motor_max_speed: float
    metrics_csv: str
    metrics_rate: float
    lidar: bool
    battery_capacity_ah: float
    battery_charge: float
    battery_drain: float
    miswire: tuple[str, ...]

    @classmethod
    def from_section(cls, section: Mapping[str, Any] | None = None) -> SimConfig:
        """Build from a [sim] section (missing keys take their defaults); every value is
        checked against :class:`SimSettings` and the keys are checked against each other."""
        values = _validated(section or {})
        _check_pairs(values)
        x, y, theta = values.pop("start_pose")
        values["miswire"] = tuple(values["miswire"])
        noise = NoiseConfig(enabled=values.pop("noise"), lidar_sigma=values.pop("lidar_noise"),
                            odom_sigma=values.pop("odom_noise"),
                            wheel_slip=values.pop("wheel_slip"), seed=values["seed"],
                            lidar_dropout=values.pop("lidar_dropout"))
        return cls(start_pose=Pose(x, y, theta), noise=noise, **values)

    @classmethod
    def from_settings(cls, settings: SimSettings) -> SimConfig:
        """From the typed [sim] settings the daemon read (the same checks as a section)."""
        return cls.from_section({f.name: getattr(settings, f.name) for f in fields(settings)})

    @property
    def physics_dt(self) -> float:
        return 1.0 / self.physics_rate

    def exact(self) -> SimConfig:
        """The same settings with every noise source switched off (the calibration errors
        are the robot's geometry, not noise: they stay)."""
        return replace(self, noise=replace(self.noise, enabled=False))

    def true_geometry(self, wheel_radius: float, wheel_separation: float) -> tuple[float, float]:
        """The simulated robot's true wheel radius and separation (m) for the configured
        ones: each off by its calibration error."""
        return (wheel_radius * (1.0 + self.wheel_radius_error),
                wheel_separation * (1.0 + self.wheel_separation_error))


def _validated(section: Mapping[str, Any]) -> dict[str, Any]:
    options = SimSettings.OPTIONS
    values = defaults(options)
    for key, raw in section.items():
        declared = options.get(key)
        if declared is None:
            raise SimConfigError(f"[sim] {key}: unknown key (valid keys: "
                                 f"{', '.join(sorted(options))})")
        value, error = declared.validate(raw)
        if error:
            raise SimConfigError(f"[sim] {key}: {error}")
        values[key] = value
    return values


def _check_pairs(values: Mapping[str, Any]) -> None:
    if values["range_min"] >= values["range_max"]:
        raise SimConfigError(f"[sim] range_min ({values['range_min']}) must be < range_max "
                             f"({values['range_max']})")
    if values["obstacle_radius_min"] > values["obstacle_radius_max"]:
        raise SimConfigError(f"[sim] obstacle_radius_min ({values['obstacle_radius_min']}) "
                             f"must be <= obstacle_radius_max "
                             f"({values['obstacle_radius_max']})")
