# The robot base as components see it: small Protocols the control loop satisfies.
from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from base.config import Config
from daemon.clock import Clock
from daemon.commands import Twist
from daemon.hooks import HookList, HookMap, Remove, Schedule
from daemon.motion_guard import MotionGuard
from sensors.rplidar.settings import LidarSettings
from sensors.scan import ScanPoints


@dataclass(frozen=True)
class Pose2D:
    """A planar pose: metres and radians."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0


class RobotBase(Protocol):
    """The robot base a component drives and reads (``ctx.robot``; the control loop is one).

    Commands from a component are *proposals* to the arbiter under a source name and a
    priority: the arbiter picks one, the collision monitor and the limiter shape it, the
    control tick writes it. Nothing here bypasses them. ``invalidations`` counts the events
    that cancel every command in flight (an e-stop, a fault, a reconnect, a stall stop),
    ``stall_invalidations`` the stall stops among them: a behaviour compares them with what
    it saw when it started.
    """

    @property
    def clock(self) -> Clock: ...

    @property
    def period_s(self) -> float: ...

    @property
    def fault(self) -> str | None: ...

    @property
    def estop_engaged(self) -> bool: ...

    @property
    def estop_reason(self) -> str: ...

    @property
    def invalidations(self) -> int: ...

    @property
    def stall_invalidations(self) -> int: ...

    def pose(self) -> Pose2D:
        """The odometry pose in the reported ``odom`` frame."""
        ...

    def pose_xyt(self) -> tuple[float, float, float]:
        """:meth:`pose` as ``(x, y, theta)`` (no object made)."""
        ...

    def integrated_pose(self) -> Pose2D:
        """The pose odometry integrated from where it started, never reset (the frame a
        reset moves is the reported one: :meth:`pose`)."""
        ...

    def heading(self) -> float:
        """The integrated heading, rad (no reset ever)."""
        ...

    def odometry_speed(self) -> float:
        """The forward speed odometry measured, m/s."""
        ...

    def limited_velocity(self) -> tuple[float, float]:
        """The limiter's current linear (m/s) and angular (rad/s) velocity."""
        ...

    def measured_wheel_speeds(self) -> tuple[float, float] | None:
        """The wheels' speeds the encoders measured (rad/s), or None (none measured yet, or
        no encoders: odometry is the command)."""
        ...

    def safety_action(self) -> str:
        """What the motion guard (the collision monitor) does now: ``none`` without one."""
        ...

    def propose(self, source: str, twist: Twist, now: float, priority: int) -> None:
        """Offer a command to the arbiter, for the next control tick."""
        ...

    def withdraw(self, source: str) -> None:
        """Take a source's command back (the robot brakes unless another source drives)."""
        ...

    async def drop_source(self, source: str) -> None:
        """Take a source's command back and apply the result at once (a client left)."""
        ...

    def set_guard(self, guard: MotionGuard) -> Remove:
        """Put the guard between the arbiter and the limiter; the remover takes it out."""
        ...

    def reset_odometry(self, x: float = 0.0, y: float = 0.0, theta: float = 0.0,
                       by: str = "") -> None:
        """Report ``(x, y, theta)`` for where the robot stands now (only the frame moves)."""
        ...

    async def sleep_to_tick(self, seconds: float) -> None:
        """Sleep about ``seconds``, waking just after a control tick."""
        ...

    def call_after_tick(self, callback: Callable[[], None]) -> asyncio.Handle:
        """Run ``callback`` after the next control tick."""
        ...


class TickHooks(Protocol):
    """Where components hook into the control tick (through their ``Plugs``)."""

    on_tick: HookList[Callable[[float, bool], None]]
    tick_sources: HookList[Callable[[float], None]]
    on_command: HookList[Callable[[str], None]]
    schedule: Schedule
    status_fields: HookMap[Callable[[], Any]]


def scan_points(config: Config) -> ScanPoints:
    """The scan converter for the ``[lidar]`` mounting pose."""
    lidar = config.get(LidarSettings)
    return ScanPoints(lidar.mount_x, lidar.mount_y, lidar.mount_yaw_deg)
