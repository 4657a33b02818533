# Planar odometry: integrate wheel travel (encoders) or the applied twist (open loop).
from __future__ import annotations

import math
from dataclasses import dataclass

from daemon.control.kinematics import DiffDrive


@dataclass(frozen=True)
class Pose2D:
    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0


class Odometry:
    """Dead reckoning with second-order (midpoint) integration."""

    def __init__(self, geometry: DiffDrive) -> None:
        self.geometry = geometry
        self.x = self.y = self.theta = 0.0
        self.linear = self.angular = 0.0
        self._last_wheels: tuple[float, float] | None = None
        self._last_t: float | None = None

    @property
    def pose(self) -> Pose2D:
        return Pose2D(self.x, self.y, self.theta)

    def update_from_encoders(self, left_rad: float, right_rad: float, t: float) -> None:
        if self._last_wheels is None or self._last_t is None:
            self._last_wheels, self._last_t = (left_rad, right_rad), t
            return
        geometry = self.geometry
        dl = (left_rad - self._last_wheels[0]) * geometry.left_radius
        dr = (right_rad - self._last_wheels[1]) * geometry.right_radius
        dt = t - self._last_t
        self._last_wheels, self._last_t = (left_rad, right_rad), t
        ds, dtheta = (dl + dr) / 2.0, (dr - dl) / geometry.separation
        self._integrate(ds, dtheta)
        if dt > 0:
            self.linear, self.angular = ds / dt, dtheta / dt

    def update_open_loop(self, linear: float, angular: float, dt: float) -> None:
        self.linear, self.angular = linear, angular
        if dt > 0:
            self._integrate(linear * dt, angular * dt)

    def reset_encoder_reference(self) -> None:
        """Forget the last wheel positions (after a driver reconnect counters may restart)."""
        self._last_wheels = None
        self._last_t = None

    def _integrate(self, ds: float, dtheta: float) -> None:
        mid = self.theta + dtheta / 2.0
        self.x += ds * math.cos(mid)
        self.y += ds * math.sin(mid)
        self.theta = math.atan2(math.sin(self.theta + dtheta), math.cos(self.theta + dtheta))
