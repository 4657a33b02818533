# [camera]: which camera, its image size and rate, where it sits, how it is streamed and recorded.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option
from drivers.camera import FPS, HEIGHT, JPEG_QUALITY, WIDTH
from drivers.picamera2_camera import CAMERA_NUM
from drivers.v4l2_camera import VIDEO_DEVICE

#: driver => the device (drivers/device_registry.py) it is; "sim" is the simulator's camera
DRIVERS = {"picamera2": "picamera2_camera", "v4l2": "v4l2_camera"}


@dataclass(frozen=True)
class CameraSectionSettings(SectionSettings, section="camera"):
    """The [camera] section: the device, the image, the mount, streaming and recording."""

    enabled: bool = option(False, "run the camera (frames are made only while someone "
                           "watches: a stream, a snapshot, a subscriber, the recorder)")
    driver: str = option("auto", "picamera2 (the Pi's CSI camera), v4l2 (a USB webcam), sim "
                         "(the simulator's view) or auto: sim under --sim, else picamera2 when "
                         "it can be imported, else v4l2",
                         choices=("auto", "picamera2", "v4l2", "sim"))
    width: int = option(**WIDTH)
    height: int = option(**HEIGHT)
    fps: float = option(**FPS)
    jpeg_quality: int = option(**JPEG_QUALITY)
    camera_num: int = option(**CAMERA_NUM)
    device: str = option(**VIDEO_DEVICE)
    frame_id: str = option("camera", "the camera's frame (header.frame_id of its images)")
    hfov_deg: float = option(62.2, "horizontal field of view, degrees (camera_info's nominal "
                             "intrinsics; the Pi camera v2: 62.2)", above=1.0, maxval=170.0)
    mount_x: float = option(0.10, "where the camera sits on the robot: ahead of base_link, m",
                            minval=-2.0, maxval=2.0)
    mount_y: float = option(0.0, "left of base_link, m", minval=-2.0, maxval=2.0)
    mount_z: float = option(0.15, "above the floor, m", above=0.0, maxval=3.0)
    mount_yaw_deg: float = option(0.0, "which way it looks from the robot's heading, degrees "
                                  "counter-clockwise", minval=-180.0, maxval=180.0)
    sim_noise: float = option(0.0, "sim: standard deviation of Gaussian pixel noise (of 255; "
                              "0 = none)", minval=0.0, maxval=64.0)
    record_rate: float = option(2.0, "frames a second the flight recorder keeps (0 = the "
                                "camera is not recorded)", minval=0.0, maxval=60.0)
    max_viewers: int = option(32, "MJPEG viewers at once (GET /api/camera/stream); more are "
                              "refused with 503", minval=1, maxval=256)
    send_timeout_s: float = option(2.0, "a viewer that takes no frame for this long is cut "
                                   "off, s", above=0.0, maxval=60.0)
    snapshot_timeout_s: float = option(3.0, "GET /api/camera/snapshot waits this long for a "
                                       "frame, s", above=0.0, maxval=30.0)
    idle_close_s: float = option(5.0, "with nobody watching for this long the camera is closed "
                                 "(a Pi camera stops), s", minval=0.0, maxval=3600.0)
