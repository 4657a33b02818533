# Planar odometry: integrate wheel travel (encoders) or the applied twist (open loop).
from __future__ import annotations

import math

from daemon.components.control.kinematics import DiffDrive
from daemon.robot import Pose2D

ORIGIN = Pose2D()


class Odometry:
    """Dead reckoning with second-order (midpoint) integration.

    ``x``, ``y``, ``theta`` integrate without a break from the start: what holds an odometry
    pose inside the daemon (the collision monitor's placed scan, wander's heading) never sees
    a jump. :meth:`reset` moves only the frame the pose is reported in (``/odom``, ``/tf``,
    ``/api/status``): :attr:`reported` is the pose in it.
    """

    def __init__(self, geometry: DiffDrive) -> None:
        self.geometry = geometry
        #: the geometry's derived figures, read once (it is frozen): every tick integrates
        self._radii = (geometry.left_radius, geometry.right_radius)
        self._separation = geometry.separation
        self.x = self.y = self.theta = 0.0
        self.linear = self.angular = 0.0
        self._last_wheels: tuple[float, float] | None = None
        self._last_t: float | None = None
        #: the integrated pose at the last reset, and the pose reported for it
        self._origin: tuple[Pose2D, Pose2D] | None = None
        self._pose = Pose2D()  # the last one made: a robot at rest asks for the same pose

    @property
    def pose(self) -> Pose2D:
        pose = self._pose
        if pose.x != self.x or pose.y != self.y or pose.theta != self.theta:
            pose = self._pose = Pose2D(self.x, self.y, self.theta)
        return pose

    @property
    def reported(self) -> Pose2D:
        """The pose in the reported frame: the integrated one, moved by the last reset."""
        if self._origin is None:
            return self.pose
        at, to = self._origin
        c, s = math.cos(at.theta), math.sin(at.theta)
        dx, dy = self.x - at.x, self.y - at.y
        ahead, left = c * dx + s * dy, -s * dx + c * dy  # travel since, in the robot's frame then
        c, s = math.cos(to.theta), math.sin(to.theta)
        theta = to.theta + self.theta - at.theta
        return Pose2D(to.x + c * ahead - s * left, to.y + s * ahead + c * left,
                      math.atan2(math.sin(theta), math.cos(theta)))

    def reported_xyt(self) -> tuple[float, float, float]:
        """:attr:`reported` as ``(x, y, theta)``."""
        if self._origin is None:
            return self.x, self.y, self.theta
        pose = self.reported
        return pose.x, pose.y, pose.theta

    def reset(self, pose: Pose2D = ORIGIN) -> None:
        """Report ``pose`` for where the robot stands now (the origin by default)."""
        self._origin = (self.pose, pose)

    def update_from_encoders(self, left_rad: float, right_rad: float, t: float) -> None:
        if self._last_wheels is None or self._last_t is None:
            self._last_wheels, self._last_t = (left_rad, right_rad), t
            return
        left_radius, right_radius = self._radii
        dl = (left_rad - self._last_wheels[0]) * left_radius
        dr = (right_rad - self._last_wheels[1]) * right_radius
        dt = t - self._last_t
        self._last_wheels, self._last_t = (left_rad, right_rad), t
        if dl == 0.0 and dr == 0.0:  # still wheels (an idle robot, most ticks): no motion
            self.linear = self.angular = 0.0
            return
        ds, dtheta = (dl + dr) / 2.0, (dr - dl) / self._separation
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
