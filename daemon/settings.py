# The core config sections ([robot], [control], [limits], [driver], [security], [logging]).
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import Option, Options
from drivers.registry import DRIVERS

ROBOT_OPTIONS: Options = {
    "name": Option(str, "arbiter", "robot name shown in /robot_info and the logs"),
    "wheel_separation": Option(float, 0.30, "distance between the wheel contact points, m",
                               above=0.0, maxval=5.0),
    "wheel_radius": Option(float, 0.05, "wheel radius, m", above=0.0, maxval=1.0),
    "wheel_separation_multiplier": Option(float, 1.0, "calibration factor on wheel_separation",
                                          above=0.0, maxval=10.0),
    "left_wheel_radius_multiplier": Option(float, 1.0, "calibration factor, left wheel radius",
                                           above=0.0, maxval=10.0),
    "right_wheel_radius_multiplier": Option(float, 1.0, "calibration factor, right wheel radius",
                                            above=0.0, maxval=10.0),
    "max_wheel_speed": Option(float, 0.0, "hard wheel speed clamp, rad/s "
                              "(0 = derived from the velocity limits)", minval=0.0),
    "base_frame_id": Option(str, "base_link", "frame of the robot body"),
    "odom_frame_id": Option(str, "odom", "frame odometry is expressed in"),
}

_COVARIANCE_DEFAULT = [0.001, 0.001, 0.001, 0.001, 0.001, 0.01]

CONTROL_OPTIONS: Options = {
    "update_rate": Option(float, 50.0, "control tick rate, Hz", minval=1.0, maxval=1000.0),
    "cmd_vel_timeout": Option(float, 0.5, "deadman: stop when no valid command for this long, s "
                              "(0 disables it, with a warning)", minval=0.0, maxval=60.0),
    "open_loop": Option(bool, False, "integrate odometry from the applied command even when the "
                        "driver has encoders"),
    "publish_rate": Option(float, 20.0, "odometry/TF publish rate, Hz", above=0.0, maxval=200.0),
    "enable_odom_tf": Option(bool, True, "publish odom -> base_link on /tf"),
    "pose_covariance_diagonal": Option(list, _COVARIANCE_DEFAULT, "odometry pose covariance "
                                       "diagonal (x, y, z, roll, pitch, yaw)", item=float,
                                       length=6, minval=0.0),
    "twist_covariance_diagonal": Option(list, _COVARIANCE_DEFAULT, "odometry twist covariance "
                                        "diagonal", item=float, length=6, minval=0.0),
    "stall_stop_s": Option(float, 0.2, "zero the wheels from a thread when the control tick "
                           "has not run for this long (blocked event loop), s (0 disables it, "
                           "with a warning)", minval=0.0, maxval=10.0),
    "rest_write_s": Option(float, 0.1, "at rest with no command, write the held zero again "
                           "at least this often, s (0 = every tick); any other command is "
                           "written at once", minval=0.0, maxval=1.0),
    "late_tick_ms": Option(float, 5.0, "a tick later than this is late: the systemd watchdog "
                           "is not pet", above=0.0, maxval=1000.0),
    "reconnect_min_s": Option(float, 0.5, "first driver reconnect delay after a fault, s",
                              above=0.0, maxval=60.0),
    "reconnect_max_s": Option(float, 10.0, "longest driver reconnect delay (back-off cap), s",
                              above=0.0, maxval=600.0),
    "allow_fault_injection": Option(bool, False, "enable POST /api/debug/stall (tests only)"),
    "wheel_mismatch_time_s": Option(float, 0.5, "stop the robot (e-stop) when a wheel's measured "
                                    "speed misses its command for this long, s (0 disables "
                                    "it; needs encoders)", minval=0.0, maxval=60.0),
    "wheel_mismatch_tolerance": Option(float, 0.5, "how far a wheel may miss its command, as a "
                                       "fraction of the commanded speed", minval=0.0,
                                       maxval=10.0),
    "wheel_mismatch_min_rad_s": Option(float, 1.5, "and always this much, rad/s (encoder "
                                       "resolution)", minval=0.0, maxval=1000.0),
    "wheel_mismatch_lag_s": Option(float, 0.3, "how long a wheel may take to follow a new "
                                   "command (motor response and measuring), s", minval=0.0,
                                   maxval=10.0),
}


def _axis_options(axis: str, unit: str, vel: float, acc: float, dec: float,
                  emergency: float) -> Options:
    return {
        f"{axis}.max_velocity": Option(float, vel, f"{axis} velocity limit, {unit}",
                                       above=0.0, maxval=100.0),
        f"{axis}.max_acceleration": Option(float, acc, f"{axis} acceleration limit, {unit}/s",
                                           above=0.0, maxval=1000.0),
        f"{axis}.max_deceleration": Option(float, dec, f"{axis} deceleration limit (slowing "
                                           f"toward zero), {unit}/s", above=0.0, maxval=1000.0),
        f"{axis}.emergency_deceleration": Option(float, emergency, f"{axis} deceleration for "
                                                 f"deadman and e-stop, {unit}/s",
                                                 above=0.0, maxval=1000.0),
        f"{axis}.max_jerk": Option(float, 0.0, f"{axis} jerk limit, {unit}/s² (0 = off)",
                                   minval=0.0, maxval=100000.0),
    }


LIMITS_OPTIONS: Options = {
    **_axis_options("linear.x", "m/s", 2.0, 1.0, 2.0, 4.0),
    **_axis_options("angular.z", "rad/s", 2.0, 4.0, 6.0, 12.0),
}

DRIVER_OPTIONS: Options = {
    "type": Option(str, "mock", "motor driver", choices=tuple(DRIVERS)),
}

SECURITY_OPTIONS: Options = {
    "token": Option(str, "", "bearer token required to move the robot, at least 12 characters "
                    "('' = none)"),
    "token_file": Option(str, "", "file holding the token (first line); '' = none"),
    "allowed_origins": Option(list, [], "extra browser origins allowed on the WebSocket "
                              "(same host and localhost are always allowed)", item=str),
    "read_requires_token": Option(bool, False, "also require the token for read-only telemetry"),
    "open_health": Option(bool, False, "answer GET /api/health without the token even when "
                          "read_requires_token = true (for monitors and deploy health checks)"),
    "allowed_hosts": Option(list, [], "extra Host names the daemon answers to, besides IP "
                            "addresses, localhost and this machine's names (incl. .local); "
                            "any other Host gets 403 (DNS rebinding guard)", item=str),
}

LOGGING_OPTIONS: Options = {
    "level": Option(str, "info", "log level", choices=("debug", "info", "warning", "error")),
    "timestamps": Option(bool, True, "start log lines with the date and time (never in the "
                         "journal under systemd: it has its own)"),
}


@dataclass(frozen=True)
class RobotSettings(SectionSettings, section="robot", options=ROBOT_OPTIONS):
    """The [robot] section, read once (keys with dots as underscores)."""

    name: str
    wheel_separation: float
    wheel_radius: float
    wheel_separation_multiplier: float
    left_wheel_radius_multiplier: float
    right_wheel_radius_multiplier: float
    max_wheel_speed: float
    base_frame_id: str
    odom_frame_id: str


@dataclass(frozen=True)
class ControlSettings(SectionSettings, section="control", options=CONTROL_OPTIONS):
    """The [control] section, read once (keys with dots as underscores)."""

    update_rate: float
    cmd_vel_timeout: float
    open_loop: bool
    publish_rate: float
    enable_odom_tf: bool
    pose_covariance_diagonal: list[float]
    twist_covariance_diagonal: list[float]
    stall_stop_s: float
    rest_write_s: float
    late_tick_ms: float
    reconnect_min_s: float
    reconnect_max_s: float
    allow_fault_injection: bool
    wheel_mismatch_time_s: float
    wheel_mismatch_tolerance: float
    wheel_mismatch_min_rad_s: float
    wheel_mismatch_lag_s: float


@dataclass(frozen=True)
class LimitsSettings(SectionSettings, section="limits", options=LIMITS_OPTIONS):
    """The [limits] section, read once (keys with dots as underscores)."""

    linear_x_max_velocity: float
    linear_x_max_acceleration: float
    linear_x_max_deceleration: float
    linear_x_emergency_deceleration: float
    linear_x_max_jerk: float
    angular_z_max_velocity: float
    angular_z_max_acceleration: float
    angular_z_max_deceleration: float
    angular_z_emergency_deceleration: float
    angular_z_max_jerk: float


@dataclass(frozen=True)
class DriverSettings(SectionSettings, section="driver", options=DRIVER_OPTIONS):
    """The [driver] section, read once (keys with dots as underscores)."""

    type: str


@dataclass(frozen=True)
class SecuritySettings(SectionSettings, section="security", options=SECURITY_OPTIONS):
    """The [security] section, read once (keys with dots as underscores)."""

    token: str
    token_file: str
    allowed_origins: list[str]
    read_requires_token: bool
    open_health: bool
    allowed_hosts: list[str]


@dataclass(frozen=True)
class LoggingSettings(SectionSettings, section="logging", options=LOGGING_OPTIONS):
    """The [logging] section, read once (keys with dots as underscores)."""

    level: str
    timestamps: bool


#: the sections no component owns (every part of the daemon reads them): these come before
#: the components' sections in the example config and the docs, and these after them
CORE_SETTINGS: tuple[type[SectionSettings], ...] = (RobotSettings, LimitsSettings, DriverSettings)
CORE_SETTINGS_LAST: tuple[type[SectionSettings], ...] = (SecuritySettings, LoggingSettings)
