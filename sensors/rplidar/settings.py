# The [lidar] config section: RPLIDAR port, scan mode, geometry of the published scan, recovery.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option


@dataclass(frozen=True)
class LidarSettings(SectionSettings, section="lidar"):
    """The [lidar] section, read once (keys with dots as underscores)."""

    enabled: bool = option(False, "read an RPLIDAR and publish /scan")
    port: str = option("/dev/rplidar", "serial port of the lidar (the udev rule's stable name)")
    baudrate: int = option(115200, "serial speed: A1/A2M8 115200, A2M7/A3/S1 256000, C1 460800, "
                           "S2/S3 1000000", minval=9600, maxval=2000000)
    scan_mode: str = option("express", "scan mode: a name the device reports (e.g. Boost, "
                            "DenseBoost), or standard | express",
                            check=lambda v: None if v.strip() else "must not be empty")
    frame_id: str = option("laser", "frame_id of the published LaserScan")
    inverted: bool = option(False, "the lidar is mounted upside down")
    angle_offset_deg: float = option(0.0, "angle of the lidar's 0° in the laser frame "
                                     "(counter-clockwise)", minval=-360.0, maxval=360.0)
    mount_x: float = option(0.0, "lidar position in the robot frame (base_link), metres forward "
                            "of the robot's origin", minval=-10.0, maxval=10.0)
    mount_y: float = option(0.0, "lidar position in the robot frame, metres to the left",
                            minval=-10.0, maxval=10.0)
    mount_yaw_deg: float = option(0.0, "direction of the laser frame's x axis in the robot frame "
                                  "(counter-clockwise)", minval=-360.0, maxval=360.0)
    angle_bins: int = option(0, "0 = one ray per sample; N = N fixed rays over 360° (angle "
                             "compensation)", minval=0, maxval=8192)
    range_min: float = option(0.15, "LaserScan range_min in metres", minval=0.0)
    range_max: float = option(0.0, "LaserScan range_max in metres (0 = what the device reports "
                              "for its mode, else 12)", minval=0.0)
    motor_pwm: int = option(660, "motor PWM for A2/A3 (0-1023); A1 uses DTR, S/C spin on their own",
                            minval=0, maxval=1023)
    request_timeout_s: float = option(2.0, "wait for a reply to a request", above=0.0)
    revolution_timeout_s: float = option(2.0, "no whole revolution for this long: restart the "
                                         "stream (STOP, RESET, scan)", above=0.0)
    reconnect_max_s: float = option(10.0, "longest back-off between reopen attempts", above=0.0)
    error_retry_s: float = option(30.0, "after a device health error, retry this often", above=0.0)
