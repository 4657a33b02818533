# Option tables of the daemon's own config sections ([robot], [control], [limits], [driver], ...).
from __future__ import annotations

import math
from typing import Any

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

HTTP_OPTIONS: Options = {
    "enabled": Option(bool, True, "serve the HTTP API"),
    "host": Option(str, "0.0.0.0", "HTTP listen address"),
    "port": Option(int, 8085, "HTTP listen port", minval=1, maxval=65535),
    "max_body_bytes": Option(int, 65536, "largest accepted request body (after "
                             "Content-Encoding), bytes; larger gets 413", minval=64,
                             maxval=16 * 1024 * 1024),
    "body_timeout_s": Option(float, 10.0, "a request body must arrive within this long, s; "
                             "slower gets 408", above=0.0, maxval=300.0),
    "idle_timeout_s": Option(float, 15.0, "close a connection that sends no complete request "
                             "line and headers for this long after it opened or after the "
                             "last answer (keep-alive and header-read timeout), s",
                             above=0.0, maxval=3600.0),
    "max_connections": Option(int, 256, "most open HTTP connections; one more closes the "
                              "oldest idle one (keep it well under LimitNOFILE)",
                              minval=4, maxval=65536),
    "console": Option(bool, True, "serve the web console at / (its files are open; what moves "
                      "the robot still needs the token)"),
}

SECURITY_OPTIONS: Options = {
    "token": Option(str, "", "bearer token required to move the robot ('' = none)"),
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
    "timestamps": Option(bool, False, "prefix log lines with a timestamp (journald adds its own)"),
}

ROSBRIDGE_OPTIONS: Options = {
    "enabled": Option(bool, True, "serve the rosbridge v2 WebSocket"),
    "host": Option(str, "0.0.0.0", "rosbridge listen address"),
    "port": Option(int, 9090, "rosbridge listen port", minval=1, maxval=65535),
    "max_clients": Option(int, 32, "most simultaneous WebSocket clients", minval=1,
                          maxval=1024),
    "reserved_clients": Option(int, 4, "of max_clients, slots only clients with the token may "
                               "take (when a token is configured)", minval=0, maxval=1024),
    "max_message_bytes": Option(int, 1048576, "largest accepted incoming message (one frame, "
                                "or one message joined from fragments), bytes",
                                minval=1024, maxval=64 * 1048576),
    "idle_timeout": Option(float, 60.0, "close a connection without the token that has sent "
                           "nothing and set nothing up (no subscription, topic or service) "
                           "for this long, s (0 = never)", minval=0.0, maxval=86400.0),
    "ops_per_second": Option(float, 1000.0, "requests one client may send per second, "
                             "sustained", above=0.0, maxval=1e9),
    "ops_burst": Option(int, 2000, "requests one client may send at once above the sustained "
                        "rate", minval=1, maxval=1_000_000_000),
    "max_topics_per_client": Option(int, 100, "topics one client may advertise", minval=1,
                                    maxval=100_000),
    "max_subscriptions_per_client": Option(int, 256, "subscriptions one client may hold "
                                           "(each subscribe id counts)", minval=1,
                                           maxval=100_000),
    "max_services_per_client": Option(int, 32, "services one client may advertise", minval=1,
                                      maxval=10_000),
    "max_pending_calls_per_client": Option(int, 64, "calls of one client waiting for "
                                           "another client's answer", minval=1,
                                           maxval=100_000),
    "call_timeout": Option(float, 30.0, "a call forwarded to a client-provided service fails "
                           "after this long; also the longest 'timeout' a call may ask for, s",
                           above=0.0, maxval=3600.0),
    "max_fragment_sets_per_client": Option(int, 8, "fragmented incoming messages one client "
                                           "may have unfinished", minval=1, maxval=1024),
    "max_fragment_bytes_per_client": Option(int, 2 * 1048576, "bytes of unfinished incoming "
                                            "fragments one client may hold, all sets together "
                                            "(UTF-8, plus 64 per fragment)", minval=1024,
                                            maxval=256 * 1048576),
    "max_fragments_per_message": Option(int, 100_000, "most fragments of one message, "
                                        "incoming ('total') or outgoing (fragment_size)",
                                        minval=1, maxval=100_000_000),
    "max_queue_length": Option(int, 100, "largest queue_length a subscription may ask for",
                               minval=1, maxval=100_000),
    "fragments_per_second": Option(float, 20_000.0, "outgoing fragments per second, all clients "
                                   "together (each costs CPU on the robot's event loop)",
                                   above=0.0, maxval=1e9),
}


def _footprint_check(value: list[Any]) -> str | None:
    """``[]`` or ``[[x, y], ...]`` with at least 3 corners (each item is checked alone too)."""
    if value and all(isinstance(item, list) for item in value):
        if len(value) < 3:
            return f"a polygon needs at least 3 [x, y] corners, got {len(value)}"
        return None
    if len(value) != 2 or not all(isinstance(v, int | float) and not isinstance(v, bool)
                                  and math.isfinite(v) for v in value):
        return f"expected a corner [x, y] of two finite numbers, got {value!r}"
    return None


COLLISION_MONITOR_OPTIONS: Options = {
    "enabled": Option(bool, True, "keep the robot out of what the lidar sees (acts only when "
                      "[lidar] is enabled; false disables it, with a warning)"),
    "footprint_radius": Option(float, 0.2, "radius of the robot's round footprint, m (used "
                               "when footprint is empty)", above=0.0, maxval=5.0),
    "footprint": Option(list, [], "polygon footprint [[x, y], ...] in the robot frame, m "
                        "(x forward, y left; the origin inside); [] = the round footprint",
                        item=list, check=_footprint_check),
    "stop_margin_m": Option(float, 0.10, "stop zone: obstacles this close to the footprint "
                            "stop any motion toward them, m", minval=0.0, maxval=2.0),
    "slowdown_margin_m": Option(float, 0.35, "slowdown zone: obstacles this close to the "
                                "footprint slow motion toward them, m", minval=0.0, maxval=5.0),
    "slowdown_ratio": Option(float, 0.5, "speed factor in the slowdown zone", above=0.0,
                             maxval=1.0),
    "time_before_collision_s": Option(float, 1.0, "approach: project the commanded motion "
                                      "this far ahead and limit speed so the robot can stop "
                                      "before the stop zone", above=0.0, maxval=10.0),
    "reaction_time_s": Option(float, 0.1, "approach: delay from a lower target to the wheels "
                              "slowing (motor and driver response), s; one control period "
                              "is added", minval=0.0, maxval=2.0),
    "min_points": Option(int, 1, "lidar points needed inside a zone before it counts (noise "
                         "filter)", minval=1, maxval=100),
    "source_timeout_s": Option(float, 0.5, "a scan older than this is stale: stale_action "
                               "applies, it never counts as no obstacle", above=0.0,
                               maxval=10.0),
    "stale_action": Option(str, "stop", "what a stale or missing scan does: stop, or slowdown "
                           "(slowdown_ratio, still limited by the last scan)",
                           choices=("stop", "slowdown")),
}

AUTONOMY_OPTIONS: Options = {
    "mode": Option(str, "off", "behaviour at start: off, or wander (drives by itself)",
                   choices=("off", "wander")),
    "cruise_speed": Option(float, 0.6, "wander: forward speed in the open, m/s", above=0.0,
                           maxval=5.0),
    "turn_speed": Option(float, 1.5, "wander: turning rate in place, rad/s", above=0.0,
                         maxval=10.0),
    "clearance_m": Option(float, 0.25, "wander: distance it keeps from obstacles (beyond the "
                          "collision monitor's footprint), m", minval=0.0, maxval=3.0),
    "look_ahead_m": Option(float, 1.6, "wander: free distance ahead at which it starts "
                           "avoiding, m", above=0.0, maxval=10.0),
    "decision_rate": Option(float, 10.0, "decisions per second", minval=1.0, maxval=100.0),
    "seed": Option(int, 0, "seed of the wander heading changes (0 = random)", minval=0),
}

RECORD_COMPRESSIONS = ("zstd", "lz4", "none")

RECORD_OPTIONS: Options = {
    "enabled": Option(bool, False, "record /odom, /tf, /scan, commands, latency reports, log "
                      "lines and health changes to MCAP files (the flight recorder)"),
    "directory": Option(str, "", "where the MCAP files go; '' = recordings/ in the service's "
                        "state directory ($STATE_DIRECTORY, /var/lib/arbiterd under systemd), "
                        "else in ~/.local/state/arbiterd"),
    "max_file_mb": Option(float, 64.0, "start a new file when the current one reaches this "
                          "size, MB", minval=1.0, maxval=4096.0),
    "max_file_s": Option(float, 900.0, "start a new file when the current one covers this "
                         "long, s", minval=10.0, maxval=86400.0),
    "max_total_mb": Option(float, 1024.0, "cap on all recordings together: the oldest files "
                           "are deleted first, MB", minval=2.0, maxval=1048576.0),
    "compression": Option(str, "zstd", "chunk compression", choices=RECORD_COMPRESSIONS),
    "flush_interval_s": Option(float, 1.0, "chunks are closed and written at least this "
                               "often: what a crash or power cut can lose, s",
                               minval=0.05, maxval=1.0),
    "queue_size": Option(int, 10000, "messages waiting for the writer thread; when full, "
                         "new ones are dropped and counted", minval=100, maxval=1000000),
}
