# USB webcams through V4L2 (linuxpy): their own MJPEG passed through, YUYV encoded with simplejpeg.
from __future__ import annotations

import asyncio
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from base.options import option, shared_option
from drivers.camera import Camera, CameraSettings
from drivers.devices import DeviceError

#: the video device, declared once (the [camera] section has it too)
VIDEO_DEVICE = shared_option("/dev/video0", "v4l2: the video device (a udev rule can give it a "
                             "stable name)")


@dataclass(frozen=True)
class V4l2Settings(CameraSettings):
    """A v4l2_camera device's keys."""

    device: str = option(**VIDEO_DEVICE)


def yuyv_to_jpeg(data: bytes, width: int, height: int, quality: int) -> bytes:
    """A packed YUYV (4:2:2) frame as JPEG, encoded from its planes without going via RGB."""
    import simplejpeg

    packed = np.frombuffer(data, dtype=np.uint8, count=width * height * 2)
    packed = packed.reshape(height, width * 2)
    y = np.ascontiguousarray(packed[:, 0::2])
    u = np.ascontiguousarray(packed[:, 1::4])
    v = np.ascontiguousarray(packed[:, 3::4])
    return bytes(simplejpeg.encode_jpeg_yuv_planes(y, u, v, quality=quality))


class V4l2Camera(Camera):
    """A V4L2 capture device asked for MJPEG at the configured size and rate. Most USB
    webcams deliver MJPEG themselves: those frames are passed through untouched (no decode,
    no re-encode). A camera that only gives YUYV is encoded here (simplejpeg, from planes)."""

    SETTINGS = V4l2Settings

    def __init__(self, options: Any, *, section: str) -> None:
        super().__init__(options, section=section)
        self.device: Any = None
        self.capture: Any = None
        self._frames: Iterator[Any] | None = None
        self.pixel_format = ""

    async def _open(self) -> None:
        await asyncio.to_thread(self.start)

    def start(self) -> None:
        try:
            from linuxpy.video.device import Device, VideoCapture
        except ImportError as exc:
            raise DeviceError(f"[{self.section}] v4l2: linuxpy is not installed ({exc}); "
                              "pip install 'arbiterd[camera]'") from None
        s = self.settings
        device = Device(s.device)
        try:
            device.open()
            capture = VideoCapture(device)
            capture.set_format(s.width, s.height, "MJPG")
            capture.set_fps(s.fps)
            capture.open()
        except Exception as exc:
            device.close()
            raise DeviceError(f"[{self.section}] v4l2: {s.device}: {exc}") from None
        self.device, self.capture = device, capture
        self._frames = iter(capture)

    def _grab(self, timeout_s: float) -> tuple[bytes, int, int]:
        if self._frames is None:
            raise DeviceError(f"[{self.section}] v4l2: not capturing")
        frame = next(self._frames)
        self.pixel_format = str(getattr(frame.pixel_format, "name", frame.pixel_format))
        width, height = int(frame.width), int(frame.height)
        if self.pixel_format in ("MJPEG", "JPEG"):
            return bytes(frame.data), width, height
        if self.pixel_format == "YUYV":
            return yuyv_to_jpeg(bytes(frame.data), width, height,
                                self.settings.jpeg_quality), width, height
        raise DeviceError(f"[{self.section}] v4l2: the camera delivers {self.pixel_format}; "
                          "arbiterd takes MJPEG or YUYV")

    async def _close(self) -> None:
        capture, device = self.capture, self.device
        self.capture = self.device = self._frames = None
        if device is not None:
            await asyncio.to_thread(_release, capture, device)

    def _health(self) -> dict[str, Any]:
        return {**super()._health(), "pixel_format": self.pixel_format}


def _release(capture: Any, device: Any) -> None:
    try:
        if capture is not None:
            capture.close()
    finally:
        device.close()
