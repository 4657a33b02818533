# The camera drivers through their libraries' APIs (picamera2 and linuxpy stand-ins that play
# recorded frames: this machine has neither a CSI camera nor a V4L2 device), and the contract.
from __future__ import annotations

import sys
import threading
import types
from typing import Any

import numpy as np
import pytest
import simplejpeg

from drivers.camera import is_jpeg
from drivers.devices import DeviceError, create_device
from drivers.picamera2_camera import MISSING
from drivers.v4l2_camera import yuyv_to_jpeg

RECORDED = simplejpeg.encode_jpeg(np.full((48, 64, 3), 90, np.uint8), colorspace="RGB")


class FakePicamera2:
    """picamera2.Picamera2 as far as the driver uses it: the encoder writes each frame to
    the output's ``write`` from a thread of its own, as picamera2's encoder thread does."""

    instances: list[FakePicamera2] = []

    def __init__(self, camera_num: int = 0) -> None:
        self.camera_num = camera_num
        self.config: Any = None
        self.recording = False
        self.closed = False
        FakePicamera2.instances.append(self)

    def create_video_configuration(self, main: dict[str, Any],
                                   controls: dict[str, Any]) -> dict[str, Any]:
        return {"main": main, "controls": controls}

    def configure(self, config: dict[str, Any]) -> None:
        self.config = config

    def start_recording(self, encoder: Any, output: Any) -> None:
        self.recording = True
        self._stop = threading.Event()

        def run() -> None:
            while not self._stop.wait(0.01):
                output.fileoutput.write(RECORDED)

        threading.Thread(target=run, daemon=True).start()

    def stop_recording(self) -> None:
        self._stop.set()
        self.recording = False

    def close(self) -> None:
        self.closed = True


@pytest.fixture
def fake_picamera2(monkeypatch: pytest.MonkeyPatch) -> type[FakePicamera2]:
    package = types.ModuleType("picamera2")
    package.Picamera2 = FakePicamera2  # type: ignore[attr-defined]
    encoders = types.ModuleType("picamera2.encoders")
    encoders.MJPEGEncoder = lambda: "hardware mjpeg"  # type: ignore[attr-defined]
    outputs = types.ModuleType("picamera2.outputs")
    outputs.FileOutput = lambda f: types.SimpleNamespace(fileoutput=f)  # type: ignore[attr-defined]
    for name, module in (("picamera2", package), ("picamera2.encoders", encoders),
                         ("picamera2.outputs", outputs)):
        monkeypatch.setitem(sys.modules, name, module)
    FakePicamera2.instances.clear()
    return FakePicamera2


async def test_picamera2_records_with_the_hardware_encoder_and_grabs_its_frames(
        fake_picamera2: type[FakePicamera2]) -> None:
    camera: Any = create_device("picamera2_camera", {"width": 64, "height": 48, "fps": 20.0},
                                section="camera")
    await camera.open()
    cam = fake_picamera2.instances[0]
    assert cam.config == {"main": {"size": (64, 48)}, "controls": {"FrameRate": 20.0}}
    first, second = camera.grab(2.0), camera.grab(2.0)
    assert first.jpeg == RECORDED and is_jpeg(second.jpeg) and camera.frames == 2
    await camera.close()
    assert cam.closed and not cam.recording
    with pytest.raises(DeviceError, match="not open"):
        camera.grab(1.0)


async def test_picamera2_missing_says_what_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "picamera2", None)  # import fails
    camera: Any = create_device("picamera2_camera", {}, section="camera")
    with pytest.raises(DeviceError) as caught:
        await camera.open()
    assert MISSING in str(caught.value) and "python3-picamera2" in str(caught.value)


class FakeFrame:
    def __init__(self, data: bytes, fmt: str, width: int, height: int) -> None:
        self.data, self.width, self.height = data, width, height
        self.pixel_format = types.SimpleNamespace(name=fmt)


def fake_linuxpy(monkeypatch: pytest.MonkeyPatch, frames: list[FakeFrame]) -> dict[str, Any]:
    seen: dict[str, Any] = {}

    class Device:
        def __init__(self, path: str) -> None:
            seen["path"] = path

        def open(self) -> None:
            seen["open"] = True

        def close(self) -> None:
            seen["closed"] = True

    class VideoCapture:
        def __init__(self, device: Device) -> None:
            pass

        def set_format(self, width: int, height: int, pixel_format: str) -> None:
            seen["format"] = (width, height, pixel_format)

        def set_fps(self, fps: float) -> None:
            seen["fps"] = fps

        def open(self) -> None:
            seen["streaming"] = True

        def close(self) -> None:
            seen["streaming"] = False

        def __iter__(self) -> Any:
            return iter(frames)

    module = types.ModuleType("linuxpy.video.device")
    module.Device, module.VideoCapture = Device, VideoCapture  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "linuxpy.video.device", module)
    return seen


async def test_v4l2_passes_mjpeg_through_untouched(monkeypatch: pytest.MonkeyPatch) -> None:
    seen = fake_linuxpy(monkeypatch, [FakeFrame(RECORDED, "MJPEG", 64, 48)])
    camera: Any = create_device("v4l2_camera", {"device": "/dev/video2", "width": 64,
                                                "height": 48, "fps": 30.0}, section="camera")
    await camera.open()
    assert seen["path"] == "/dev/video2" and seen["format"] == (64, 48, "MJPG")
    assert seen["fps"] == 30.0
    frame = camera.grab(1.0)
    assert frame.jpeg == RECORDED  # the very bytes the camera gave
    await camera.close()
    assert seen["closed"] and not seen["streaming"]


async def test_v4l2_encodes_yuyv_and_refuses_other_formats(
        monkeypatch: pytest.MonkeyPatch) -> None:
    yuyv = np.tile(np.array([128, 100, 128, 150], np.uint8), 64 * 48 // 2).tobytes()
    fake_linuxpy(monkeypatch, [FakeFrame(yuyv, "YUYV", 64, 48),
                               FakeFrame(b"\x00" * 10, "RGB24", 64, 48)])
    camera: Any = create_device("v4l2_camera", {"width": 64, "height": 48},
                                section="camera")
    await camera.open()
    frame = camera.grab(1.0)
    assert simplejpeg.decode_jpeg(frame.jpeg).shape == (48, 64, 3)
    with pytest.raises(DeviceError, match="RGB24"):
        camera.grab(1.0)
    assert camera.fault is not None and "RGB24" in camera.fault


def test_yuyv_planes_keep_the_picture() -> None:
    gray = np.tile(np.array([200, 128, 200, 128], np.uint8), 32 * 16 // 2).tobytes()
    image = simplejpeg.decode_jpeg(yuyv_to_jpeg(gray, 32, 16, 90))
    assert abs(float(image.mean()) - 200) < 4


@pytest.mark.parametrize("options", [{"width": 0}, {"fps": float("nan")}, {"fps": 1e308},
                                     {"jpeg_quality": 101}, {"width": "640"}])
def test_bad_options_are_refused_naming_the_key(options: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match=r"\[camera\]"):
        create_device("v4l2_camera", options, section="camera")
