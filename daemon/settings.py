# The core config sections ([robot], [control], [limits], [driver], [security], [logging]).
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from base.config import SectionSettings
from base.options import option
from drivers.registry import DRIVERS

_COVARIANCE_DEFAULT = [0.001, 0.001, 0.001, 0.001, 0.001, 0.01]


# The five keys of each [limits] axis ("linear.x", "angular.z"; unit "m/s" or "rad/s").
def _max_velocity(axis: str, unit: str, default: float) -> Any:
    return option(default, f"{axis} velocity limit, {unit}", above=0.0, maxval=100.0,
                  key=f"{axis}.max_velocity")


def _max_acceleration(axis: str, unit: str, default: float) -> Any:
    return option(default, f"{axis} acceleration limit, {unit}/s", above=0.0, maxval=1000.0,
                  key=f"{axis}.max_acceleration")


def _max_deceleration(axis: str, unit: str, default: float) -> Any:
    return option(default, f"{axis} deceleration limit (slowing toward zero), {unit}/s",
                  above=0.0, maxval=1000.0, key=f"{axis}.max_deceleration")


def _emergency_deceleration(axis: str, unit: str, default: float) -> Any:
    return option(default, f"{axis} deceleration for deadman and e-stop, {unit}/s", above=0.0,
                  maxval=1000.0, key=f"{axis}.emergency_deceleration")


def _max_jerk(axis: str, unit: str) -> Any:
    return option(0.0, f"{axis} jerk limit, {unit}/s² (0 = off)", minval=0.0, maxval=100000.0,
                  key=f"{axis}.max_jerk")


@dataclass(frozen=True)
class RobotSettings(SectionSettings, section="robot"):
    """The [robot] section, read once (keys with dots as underscores)."""

    name: str = option("arbiter", "robot name shown in /robot_info and the logs")
    wheel_separation: float = option(0.30, "distance between the wheel contact points, m",
                                     above=0.0, maxval=5.0)
    wheel_radius: float = option(0.05, "wheel radius, m", above=0.0, maxval=1.0)
    wheel_separation_multiplier: float = option(1.0, "calibration factor on wheel_separation",
                                                above=0.0, maxval=10.0)
    left_wheel_radius_multiplier: float = option(1.0, "calibration factor, left wheel radius",
                                                 above=0.0, maxval=10.0)
    right_wheel_radius_multiplier: float = option(1.0, "calibration factor, right wheel radius",
                                                  above=0.0, maxval=10.0)
    max_wheel_speed: float = option(0.0, "hard wheel speed clamp, rad/s (0 = derived from the "
                                    "velocity limits)", minval=0.0)
    base_frame_id: str = option("base_link", "frame of the robot body")
    odom_frame_id: str = option("odom", "frame odometry is expressed in")


@dataclass(frozen=True)
class ControlSettings(SectionSettings, section="control"):
    """The [control] section, read once (keys with dots as underscores)."""

    update_rate: float = option(50.0, "control tick rate, Hz", minval=1.0, maxval=1000.0)
    cmd_vel_timeout: float = option(0.5, "deadman: stop when no valid command for this long, s (0 "
                                    "disables it, with a warning)", minval=0.0, maxval=60.0)
    open_loop: bool = option(False, "integrate odometry from the applied command even when the "
                             "driver has encoders")
    publish_rate: float = option(20.0, "odometry/TF publish rate, Hz", above=0.0, maxval=200.0)
    enable_odom_tf: bool = option(True, "publish odom -> base_link on /tf")
    pose_covariance_diagonal: list[float] = option(_COVARIANCE_DEFAULT, "odometry pose covariance "
                                                   "diagonal (x, y, z, roll, pitch, yaw)", length=6,
                                                   minval=0.0)
    twist_covariance_diagonal: list[float] = option(_COVARIANCE_DEFAULT, "odometry twist "
                                                    "covariance diagonal", length=6, minval=0.0)
    stall_stop_s: float = option(0.2, "zero the wheels from a thread when the control tick has "
                                 "not run for this long (blocked event loop), s (0 disables it, "
                                 "with a warning)", minval=0.0, maxval=10.0)
    rest_write_s: float = option(0.1, "at rest with no command, write the held zero again at "
                                 "least this often, s (0 = every tick); any other command is "
                                 "written at once", minval=0.0, maxval=1.0)
    late_tick_ms: float = option(5.0, "a tick later than this is late: the systemd watchdog is "
                                 "not pet", above=0.0, maxval=1000.0)
    reconnect_min_s: float = option(0.5, "first driver reconnect delay after a fault, s", above=0.0,
                                    maxval=60.0)
    reconnect_max_s: float = option(10.0, "longest driver reconnect delay (back-off cap), s",
                                    above=0.0, maxval=600.0)
    allow_fault_injection: bool = option(False, "enable POST /api/debug/stall (tests only)")
    wheel_mismatch_time_s: float = option(0.5, "stop the robot (e-stop) when a wheel's measured "
                                          "speed misses its command for this long, s (0 disables "
                                          "it; needs encoders)", minval=0.0, maxval=60.0)
    wheel_mismatch_tolerance: float = option(0.5, "how far a wheel may miss its command, as a "
                                             "fraction of the commanded speed", minval=0.0,
                                             maxval=10.0)
    wheel_mismatch_min_rad_s: float = option(1.5, "and always this much, rad/s (encoder "
                                             "resolution)", minval=0.0, maxval=1000.0)
    wheel_mismatch_lag_s: float = option(0.3, "how long a wheel may take to follow a new command "
                                         "(motor response and measuring), s", minval=0.0,
                                         maxval=10.0)


@dataclass(frozen=True)
class LimitsSettings(SectionSettings, section="limits"):
    """The [limits] section, read once (keys with dots as underscores)."""

    linear_x_max_velocity: float = _max_velocity("linear.x", "m/s", 2.0)
    linear_x_max_acceleration: float = _max_acceleration("linear.x", "m/s", 1.0)
    linear_x_max_deceleration: float = _max_deceleration("linear.x", "m/s", 2.0)
    linear_x_emergency_deceleration: float = _emergency_deceleration("linear.x", "m/s", 4.0)
    linear_x_max_jerk: float = _max_jerk("linear.x", "m/s")
    angular_z_max_velocity: float = _max_velocity("angular.z", "rad/s", 2.0)
    angular_z_max_acceleration: float = _max_acceleration("angular.z", "rad/s", 4.0)
    angular_z_max_deceleration: float = _max_deceleration("angular.z", "rad/s", 6.0)
    angular_z_emergency_deceleration: float = _emergency_deceleration("angular.z", "rad/s", 12.0)
    angular_z_max_jerk: float = _max_jerk("angular.z", "rad/s")


@dataclass(frozen=True)
class DriverSettings(SectionSettings, section="driver"):
    """The [driver] section, read once (keys with dots as underscores)."""

    type: str = option("mock", "motor driver", choices=tuple(DRIVERS))


@dataclass(frozen=True)
class SecuritySettings(SectionSettings, section="security"):
    """The [security] section, read once (keys with dots as underscores)."""

    token: str = option("", "bearer token required to move the robot, at least 12 characters ('' "
                        "= none)")
    token_file: str = option("", "file holding the token (first line); '' = none")
    allowed_origins: list[str] = option([], "extra browser origins allowed on the WebSocket (same "
                                        "host and localhost are always allowed)")
    read_requires_token: bool = option(False, "also require the token for read-only telemetry")
    open_health: bool = option(False, "answer GET /api/health without the token even when "
                               "read_requires_token = true (for monitors and deploy health checks)")
    allowed_hosts: list[str] = option([], "extra Host names the daemon answers to, besides IP "
                                      "addresses, localhost and this machine's names (incl. "
                                      ".local); any other Host gets 403 (DNS rebinding guard)")


@dataclass(frozen=True)
class LoggingSettings(SectionSettings, section="logging"):
    """The [logging] section, read once (keys with dots as underscores)."""

    level: str = option("info", "log level", choices=("debug", "info", "warning", "error"))
    timestamps: bool = option(True, "start log lines with the date and time (never in the journal "
                              "under systemd: it has its own)")


#: the sections no component owns (every part of the daemon reads them): these come before
#: the components' sections in the example config and the docs, and these after them
CORE_SETTINGS: tuple[type[SectionSettings], ...] = (RobotSettings, LimitsSettings, DriverSettings)
CORE_SETTINGS_LAST: tuple[type[SectionSettings], ...] = (SecuritySettings, LoggingSettings)
