# Differential-drive kinematics: body twist <-> wheel speeds, with calibration multipliers.
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from daemon.settings import RobotSettings


@dataclass(frozen=True)
class DiffDrive:
    """Geometry of a two-wheeled differential-drive base (diff_drive_controller names)."""

    wheel_separation: float
    wheel_radius: float
    wheel_separation_multiplier: float = 1.0
    left_wheel_radius_multiplier: float = 1.0
    right_wheel_radius_multiplier: float = 1.0
    #: (separation / 2, left radius, right radius), computed once: every control step uses them
    _per_wheel: tuple[float, float, float] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_per_wheel", (self.separation / 2.0, self.left_radius,
                                                self.right_radius))

    @classmethod
    def from_settings(cls, robot: RobotSettings) -> DiffDrive:
        return cls(robot.wheel_separation, robot.wheel_radius,
                   robot.wheel_separation_multiplier, robot.left_wheel_radius_multiplier,
                   robot.right_wheel_radius_multiplier)

    @property
    def separation(self) -> float:
        return self.wheel_separation * self.wheel_separation_multiplier

    @property
    def left_radius(self) -> float:
        return self.wheel_radius * self.left_wheel_radius_multiplier

    @property
    def right_radius(self) -> float:
        return self.wheel_radius * self.right_wheel_radius_multiplier

    def wheel_speeds(self, linear_x: float, angular_z: float) -> tuple[float, float]:
        """Body (m/s, rad/s) -> wheels (rad/s)."""
        half_separation, left_radius, right_radius = self._per_wheel
        half = angular_z * half_separation
        return (linear_x - half) / left_radius, (linear_x + half) / right_radius

    def body_twist(self, left_rad_s: float, right_rad_s: float) -> tuple[float, float]:
        """Wheels (rad/s) -> body (m/s, rad/s)."""
        vl, vr = left_rad_s * self.left_radius, right_rad_s * self.right_radius
        return (vl + vr) / 2.0, (vr - vl) / self.separation

    def max_wheel_speed(self, max_linear: float, max_angular: float) -> float:
        """The fastest wheel speed the velocity limits can ask for, rad/s."""
        fastest = max_linear + max_angular * self.separation / 2.0
        return fastest / min(self.left_radius, self.right_radius)


def scale_to_limit(left: float, right: float, limit: float) -> tuple[float, float, bool]:
    """Scale both wheels down together so neither exceeds ``limit`` (keeps the curvature)."""
    fastest = max(abs(left), abs(right))
    if fastest <= limit or fastest == 0.0:
        return left, right, False
    k = limit / fastest
    return left * k, right * k, True
