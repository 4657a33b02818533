# The Pi's CSI camera through picamera2 (libcamera), JPEG from the Pi's hardware MJPEG encoder.
from __future__ import annotations

import asyncio
import importlib
import io
import threading
from dataclasses import dataclass
from typing import Any

from base.options import option, shared_option
from drivers.camera import Camera, CameraSettings
from drivers.devices import DeviceError

#: which CSI camera, declared once (the [camera] section has it too)
CAMERA_NUM = shared_option(0, "picamera2: which CSI camera (0 = the first)", minval=0, maxval=7)

#: what to do when the library is missing (install.sh and ``arbiterd check`` say the same)
MISSING = ("picamera2 cannot be imported from arbiterd's Python: install Raspberry Pi OS's "
           "python3-picamera2 (apt install python3-picamera2) and let the venv see the system "
           "packages (sudo ./install.sh systemd --camera does both)")


def import_picamera2() -> tuple[Any, Any, Any]:
    """picamera2's Picamera2, MJPEGEncoder and FileOutput, or DeviceError saying what to do."""
    try:
        picamera2 = importlib.import_module("picamera2")
        encoders = importlib.import_module("picamera2.encoders")
        outputs = importlib.import_module("picamera2.outputs")
    except ImportError as exc:
        raise DeviceError(f"{MISSING} ({exc})") from None
    return picamera2.Picamera2, encoders.MJPEGEncoder, outputs.FileOutput


@dataclass(frozen=True)
class Picamera2Settings(CameraSettings):
    """A picamera2_camera device's keys."""

    camera_num: int = option(**CAMERA_NUM)


class LatestJpeg(io.BufferedIOBase):
    """What picamera2's FileOutput writes each encoded frame to: keeps the newest one and
    wakes whoever waits for it (one frame held, whatever the reader's pace)."""

    def __init__(self) -> None:
        self.frame: bytes | None = None
        self.count = 0
        self.ready = threading.Condition()

    def writable(self) -> bool:
        return True

    def write(self, data: Any) -> int:
        frame = bytes(data)
        with self.ready:
            self.frame, self.count = frame, self.count + 1
            self.ready.notify_all()
        return len(frame)

    def next_after(self, count: int, timeout_s: float) -> tuple[bytes, int] | None:
        with self.ready:
            if not self.ready.wait_for(lambda: self.count > count and self.frame is not None,
                                       timeout_s):
                return None
            assert self.frame is not None
            return self.frame, self.count


class Picamera2Camera(Camera):
    """libcamera's camera through picamera2: a video configuration at the configured size
    and rate, recorded with ``MJPEGEncoder`` (the Pi 4's hardware encoder) into
    :class:`LatestJpeg`; :meth:`grab` returns the next frame it wrote. Recording runs only
    between open and close (the component opens the camera while someone watches)."""

    SETTINGS = Picamera2Settings

    def __init__(self, options: Any, *, section: str) -> None:
        super().__init__(options, section=section)
        self.camera: Any = None
        self.output = LatestJpeg()
        self._seen = 0

    async def _open(self) -> None:
        await asyncio.to_thread(self.start)

    def start(self) -> None:
        picamera2_class, encoder_class, file_output = import_picamera2()
        s = self.settings
        try:
            camera = picamera2_class(s.camera_num)
        except Exception as exc:  # no camera connected, libcamera busy
            raise DeviceError(f"[{self.section}] picamera2: camera {s.camera_num}: "
                              f"{exc}") from None
        try:
            config = camera.create_video_configuration(
                main={"size": (s.width, s.height)},
                controls={"FrameRate": float(s.fps)})
            camera.configure(config)
            camera.start_recording(encoder_class(), file_output(self.output))
        except Exception as exc:
            camera.close()
            raise DeviceError(f"[{self.section}] picamera2: {exc}") from None
        self.camera = camera

    def _grab(self, timeout_s: float) -> tuple[bytes, int, int]:
        got = self.output.next_after(self._seen, timeout_s)
        if got is None:
            raise DeviceError(f"[{self.section}] picamera2: no frame within {timeout_s:g} s")
        jpeg, self._seen = got
        return jpeg, self.settings.width, self.settings.height

    async def _close(self) -> None:
        camera, self.camera = self.camera, None
        if camera is not None:
            await asyncio.to_thread(_stop, camera)


def _stop(camera: Any) -> None:
    try:
        camera.stop_recording()
    finally:
        camera.close()
