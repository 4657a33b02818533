# The simulated camera: the planar world drawn as a pseudo-3-D view, one ray cast per column.
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sim.objects import OBJECT_COLORS, OBJECT_HEIGHT, cast_circles
from sim.raycast import RayCaster
from sim.world import World

#: how tall the world's walls and round obstacles are drawn (m)
WALL_HEIGHT = 1.0
OBSTACLE_HEIGHT = 0.8
#: the floor's checker squares (m): they show distance and motion
FLOOR_TILE_M = 0.5
WALL_RGB = np.array([200, 196, 184], dtype=np.float32)
OBSTACLE_RGB = np.array([150, 105, 70], dtype=np.float32)
FLOOR_RGB = (np.array([120, 120, 128], dtype=np.float32),
             np.array([92, 92, 100], dtype=np.float32))
SKY_TOP, SKY_HORIZON = np.array([150, 170, 200.0]), np.array([215, 220, 228.0])
#: the farthest anything is drawn (m)
VIEW_RANGE_M = 40.0


@dataclass(frozen=True)
class CameraModel:
    """A level pinhole camera on the robot: image size, horizontal field of view and where
    it sits in base_link (x forward, y left, z up, m; yaw, rad). Rows grow downwards, columns
    to the right; column ``u`` looks ``atan((cx - u) / f)`` to the left of the optical axis."""

    width: int = 640
    height: int = 480
    hfov_rad: float = math.radians(62.2)
    x: float = 0.10
    y: float = 0.0
    z: float = 0.15
    yaw: float = 0.0

    @property
    def f(self) -> float:
        """Focal length in pixels (square pixels)."""
        return (self.width / 2.0) / math.tan(self.hfov_rad / 2.0)

    @property
    def cx(self) -> float:
        return self.width / 2.0

    @property
    def cy(self) -> float:
        return self.height / 2.0

    def column_angles(self) -> np.ndarray:
        """The bearing of each pixel column's centre from the optical axis (rad, left +)."""
        u = np.arange(self.width, dtype=float) + 0.5
        return np.asarray(np.arctan2(self.cx - u, self.f))

    def pose_in_world(self, x: float, y: float, theta: float) -> tuple[float, float, float]:
        """Where the camera is and looks, for the robot at (x, y, theta)."""
        c, s = math.cos(theta), math.sin(theta)
        return x + c * self.x - s * self.y, y + s * self.x + c * self.y, theta + self.yaw

    def row(self, depth: np.ndarray | float, height: float) -> np.ndarray:
        """The image row of a point ``height`` m above the floor ``depth`` m ahead."""
        return np.asarray(self.cy + self.f * (self.z - height) / np.asarray(depth))

    def ground_depth(self, row: float) -> float:
        """How far ahead (m) the floor is seen at image row ``row`` (inf at or above the
        horizon)."""
        below = row - self.cy
        return self.f * self.z / below if below > 0 else math.inf

    def intrinsics(self) -> list[float]:
        """K, row-major 3x3 (sensor_msgs/CameraInfo)."""
        return [self.f, 0.0, self.cx, 0.0, self.f, self.cy, 0.0, 0.0, 1.0]


class CameraRenderer:
    """Draws what the camera of ``model`` sees in ``world``: sky, a checkered floor, walls
    and round obstacles (one ray cast per column, shaded by distance) and the standing
    objects in their colours over them where nearer. ``noise`` is the standard deviation of
    Gaussian pixel noise (0: none); ``seed`` makes it reproducible. Returns ``(height, width,
    3)`` uint8 RGB."""

    def __init__(self, world: World, model: CameraModel, *, noise: float = 0.0,
                 seed: int = 0) -> None:
        self.world = world
        self.model = model
        self.noise = noise
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self.angles = model.column_angles()
        self._cos = np.cos(self.angles)
        walls = World(world.segments, ()) if world.segments else None
        pillars = World((), world.circles) if world.circles else None
        self._walls = RayCaster(walls, self.angles, 0.0, VIEW_RANGE_M) if walls else None
        self._pillars = RayCaster(pillars, self.angles, 0.0, VIEW_RANGE_M) if pillars else None
        rows = np.arange(model.height, dtype=np.float32)[:, None] + 0.5
        self._rows = rows
        self._floor_rows = np.nonzero(rows[:, 0] > model.cy + 0.5)[0]
        below = rows[self._floor_rows, 0] - model.cy
        self._floor_depth = (model.f * model.z / below).astype(np.float32)  # per floor row
        self._tan = np.tan(self.angles).astype(np.float32)
        sky = np.clip((rows[:, 0] / max(model.cy, 1.0))[:, None], 0.0, 1.0)
        self._sky = np.broadcast_to((SKY_TOP + (SKY_HORIZON - SKY_TOP) * sky)[:, None, :],
                                    (model.height, model.width, 3)).astype(np.uint8)
        # the floor's two tile colours per row, shaded by distance and hazed (uint8)
        shade = (1.0 / (1.0 + 0.08 * self._floor_depth))[:, None]
        haze = SKY_HORIZON * (1.0 - shade) * 0.6
        self._floor_a = np.clip(FLOOR_RGB[0] * shade + haze, 0, 255).astype(np.uint8)[:, None]
        self._floor_b = np.clip(FLOOR_RGB[1] * shade + haze, 0, 255).astype(np.uint8)[:, None]

    def render(self, pose: tuple[float, float, float],
               objects: Sequence[tuple[float, float, float, str]] = ()) -> np.ndarray:
        """The view of the robot at ``pose`` (x, y, theta) with ``objects`` standing (x, y,
        radius, colour)."""
        cam_x, cam_y, heading = self.model.pose_in_world(*pose)
        image = self._sky.copy()
        self._floor(image, cam_x, cam_y, heading)
        spans: list[tuple[np.ndarray, float, np.ndarray]] = []
        for caster, height, rgb in ((self._walls, WALL_HEIGHT, WALL_RGB),
                                    (self._pillars, OBSTACLE_HEIGHT, OBSTACLE_RGB)):
            if caster is not None:
                spans.append((caster.cast(cam_x, cam_y, heading) * self._cos, height, rgb))
        for x, y, r, color in objects:
            ranges = cast_circles(np.full(self.model.width, np.inf),
                                  np.array([[x, y, r]]), cam_x, cam_y, heading, self.angles)
            spans.append((ranges * self._cos, OBJECT_HEIGHT,
                          np.array(OBJECT_COLORS.get(color, (255, 255, 255)), np.float32)))
        self._paint(image, spans)
        if self.noise > 0:
            noisy = image + self._rng.normal(0.0, self.noise, image.shape)
            return np.ascontiguousarray(np.clip(noisy, 0, 255).astype(np.uint8))
        return image

    def _floor(self, image: np.ndarray, cam_x: float, cam_y: float, heading: float) -> None:
        depth = self._floor_depth[:, None]
        c, s = math.cos(heading), math.sin(heading)
        tile = np.float32(1.0 / FLOOR_TILE_M)
        wx = (cam_x * tile + depth * (c - self._tan * s)[None, :] * tile)
        wy = (cam_y * tile + depth * (s + self._tan * c)[None, :] * tile)
        checker = ((np.floor(wx) + np.floor(wy)) % 2).astype(bool)
        image[self._floor_rows] = np.where(checker[..., None], self._floor_a, self._floor_b)

    def _paint(self, image: np.ndarray,
               spans: list[tuple[np.ndarray, float, np.ndarray]]) -> None:
        """Each span (depth per column, height, colour) over what is behind it: a label per
        pixel (which span is in front), then one lookup of the shaded colours."""
        width = self.model.width
        nearest = np.full(width, np.inf)
        label = np.zeros(image.shape[:2], dtype=np.int16)
        table = np.zeros((len(spans) + 1, width, 3), dtype=np.uint8)
        order = sorted(range(len(spans)), key=lambda i: -float(np.min(spans[i][0],
                                                                         initial=np.inf)))
        rows = self._rows
        for index in order:
            depth, height, rgb = spans[index]
            seen = np.isfinite(depth) & (depth > 1e-3)
            if not seen.any():
                continue
            d = np.where(seen, depth, 1.0)
            top = np.where(seen, self.model.row(d, height), np.inf)
            bottom = np.where(seen, self.model.row(d, 0.0), -np.inf)
            # in front of what was painted in that column (spans overlap in depth order)
            front = seen & (depth <= nearest)
            top[~front], bottom[~front] = np.inf, -np.inf
            mask = (rows >= top[None, :]) & (rows <= bottom[None, :])
            label[mask] = index + 1
            shade = 1.0 / (1.0 + 0.12 * d)
            colour = rgb[None, :] * shade[:, None] + SKY_HORIZON * (1.0 - shade[:, None]) * 0.5
            table[index + 1] = np.clip(colour, 0, 255).astype(np.uint8)
            np.minimum(nearest, np.where(front, depth, np.inf), out=nearest)
        painted = label > 0
        columns = np.broadcast_to(np.arange(width), label.shape)
        image[painted] = table[label[painted], columns[painted]]


def encode_jpeg(image: np.ndarray, quality: int = 80) -> bytes:
    """An RGB image as JPEG (simplejpeg: libjpeg-turbo)."""
    import simplejpeg

    return bytes(simplejpeg.encode_jpeg(image, quality=quality, colorspace="RGB"))
