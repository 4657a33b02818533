# The simulator's camera as a camera device: the simulated world drawn from the robot's true pose.
from __future__ import annotations

from typing import Any

from drivers.camera import Camera
from sim.camera import CameraModel, CameraRenderer, encode_jpeg
from sim.stepper import SimWorld


class SimCamera(Camera):
    """Renders ``world`` as the camera of ``model`` sees it (sim/camera.py) and encodes it
    with simplejpeg; :attr:`last_image` keeps the last RGB image (the detector's input)."""

    def __init__(self, options: Any, *, section: str, world: SimWorld, model: CameraModel,
                 noise: float = 0.0, seed: int = 0) -> None:
        super().__init__(options, section=section)
        self.world = world
        self.model = model
        self.renderer = CameraRenderer(world.world, model, noise=noise, seed=seed)

    async def _open(self) -> None:
        return None

    async def _close(self) -> None:
        return None

    def _grab(self, timeout_s: float) -> tuple[bytes, int, int]:
        pose, objects = self.world.camera_view()
        image = self.renderer.render(pose, objects)
        return encode_jpeg(image, self.settings.jpeg_quality), self.model.width, \
            self.model.height
