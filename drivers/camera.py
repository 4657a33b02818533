# The camera device contract: open, grab one JPEG frame (blocking, off the event loop), close.
from __future__ import annotations

import math
import threading
import time
from abc import abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

from base.options import option, shared_option
from drivers.devices import Device, DeviceError

#: the keys every camera has, declared once (the [camera] section has them too)
WIDTH = shared_option(640, "image width, pixels", minval=16, maxval=4096)
HEIGHT = shared_option(480, "image height, pixels", minval=16, maxval=3072)
FPS = shared_option(15.0, "frames per second while someone watches", above=0.0, maxval=60.0)
JPEG_QUALITY = shared_option(80, "JPEG quality where arbiterd or the camera encodes (1..100)",
                             minval=1, maxval=100)


@dataclass(frozen=True, slots=True)
class Frame:
    """One JPEG image and when it was taken (``stamp``: wall clock, s; ``t``: the caller's
    clock, monotonic or simulated)."""

    jpeg: bytes
    width: int
    height: int
    stamp: float
    t: float
    #: ms spent making it (render or capture wait + encode), for health and the bench
    cost_ms: float = 0.0


@dataclass(frozen=True)
class CameraSettings:
    """The keys every camera device has."""

    width: int = option(**WIDTH)
    height: int = option(**HEIGHT)
    fps: float = option(**FPS)
    jpeg_quality: int = option(**JPEG_QUALITY)


class Camera(Device):
    """A camera: :meth:`grab` blocks until the next frame (call it from a worker thread, never
    the event loop) and returns it as JPEG. The base checks it is open, times the grab and
    turns a failure into :class:`DeviceError` with ``fault`` set; a subclass implements
    ``_grab``. ``frames`` counts what it delivered."""

    KIND = "camera"
    SETTINGS: ClassVar[type[Any]] = CameraSettings

    def __init__(self, options: Any, *, section: str) -> None:
        super().__init__(options, section=section)
        self.frames = 0
        self._lock = threading.Lock()

    def grab(self, timeout_s: float = 2.0) -> Frame:
        if not self.is_open:
            raise DeviceError(f"[{self.section}] camera is not open")
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise DeviceError(f"[{self.section}] grab timeout must be > 0, got {timeout_s}")
        started = time.perf_counter()
        try:
            with self._lock:
                jpeg, width, height = self._grab(timeout_s)
        except DeviceError as exc:
            self.fault = str(exc)
            raise
        except Exception as exc:  # a library's own error: one line, the device is faulty
            self.fault = f"[{self.section}] {type(exc).__name__}: {exc}"
            raise DeviceError(self.fault) from exc
        self.frames += 1
        return Frame(jpeg, width, height, time.time(), time.monotonic(),
                     (time.perf_counter() - started) * 1000.0)

    @abstractmethod
    def _grab(self, timeout_s: float) -> tuple[bytes, int, int]:
        """The next frame: JPEG bytes, width, height (blocking, at most ``timeout_s``)."""

    def _health(self) -> dict[str, Any]:
        s = self.settings
        return {"frames": self.frames, "width": s.width, "height": s.height, "fps": s.fps}


def is_jpeg(data: bytes) -> bool:
    """Starts with a JPEG SOI marker and ends with EOI (trailing padding allowed)."""
    return len(data) > 4 and data[:2] == b"\xff\xd8" and b"\xff\xd9" in data[-16:]
