# The simulator's camera as a camera device: the world drawn from the robot's true pose in a
# worker process (numpy drawing holds the GIL in small steps: out of the daemon's process, the
# control tick never waits behind it).
from __future__ import annotations

import asyncio
import multiprocessing
from multiprocessing.connection import Connection
from typing import Any

from drivers.camera import Camera
from drivers.devices import DeviceError
from sim.camera import CameraModel, CameraRenderer, encode_jpeg
from sim.stepper import SimWorld
from sim.world import World

#: how long the worker may take to start, s
START_TIMEOUT_S = 30.0


def render_worker(conn: Connection, world: World, model: CameraModel, noise: float,
                  seed: int) -> None:
    """The worker process: (pose, objects, quality) in, JPEG bytes out, until EOF."""
    renderer = CameraRenderer(world, model, noise=noise, seed=seed)
    conn.send_bytes(b"ready")
    while True:
        try:
            pose, objects, quality = conn.recv()
        except EOFError:
            return
        conn.send_bytes(encode_jpeg(renderer.render(pose, objects), quality))


class SimCamera(Camera):
    """Renders ``world`` as the camera of ``model`` sees it (sim/camera.py) and encodes it
    with simplejpeg, in a worker process started on open and ended on close; :meth:`grab`
    sends it the true pose and the standing objects and waits for the JPEG."""

    def __init__(self, options: Any, *, section: str, world: SimWorld, model: CameraModel,
                 noise: float = 0.0, seed: int = 0) -> None:
        super().__init__(options, section=section)
        self.world = world
        self.model = model
        self.noise = noise
        self.seed = seed
        self._process: Any = None
        self._conn: Connection | None = None
        #: set by a close: a start still running in its thread ends its worker at once
        self._closing = False

    async def _open(self) -> None:
        self._closing = False
        await asyncio.to_thread(self._start)

    def _start(self) -> None:
        context = multiprocessing.get_context("spawn")
        parent, child = context.Pipe()
        process = context.Process(target=render_worker, name="arbiterd-camera-sim",
                                  args=(child, self.world.world, self.model, self.noise,
                                        self.seed), daemon=True)
        process.start()
        child.close()
        if not parent.poll(START_TIMEOUT_S) or parent.recv_bytes() != b"ready":
            process.kill()
            raise DeviceError(f"[{self.section}] sim: the render worker did not start")
        self._process, self._conn = process, parent
        if self._closing:  # closed while this start ran: nobody will ever end the worker
            self._process = self._conn = None
            parent.close()
            _end(process)

    async def _close(self) -> None:
        self._closing = True
        conn, process = self._conn, self._process
        self._conn = self._process = None
        if conn is not None:
            conn.close()
        if process is not None:
            await asyncio.to_thread(_end, process)

    def _grab(self, timeout_s: float) -> tuple[bytes, int, int]:
        conn = self._conn
        if conn is None:
            raise DeviceError(f"[{self.section}] sim: not open")
        pose, objects = self.world.camera_view()
        try:
            conn.send((pose, objects, self.settings.jpeg_quality))
            if not conn.poll(timeout_s):
                raise DeviceError(f"[{self.section}] sim: no frame within {timeout_s:g} s")
            jpeg = conn.recv_bytes()
        except (OSError, EOFError) as exc:
            raise DeviceError(f"[{self.section}] sim: the render worker is gone ({exc})") \
                from None
        return jpeg, self.model.width, self.model.height


def _end(process: Any) -> None:
    process.join(2.0)
    if process.is_alive():
        process.kill()
        process.join(2.0)
