# The final approach onto the dock and the dock's estimate from fits (pure, clockless).
from __future__ import annotations

import math
from dataclasses import dataclass

from slam.pose import Pose2, between

#: the heading that brings the robot onto the dock's axis aims this far ahead along it (m)
LOOKAHEAD_M = 0.15
#: heading errors above this are turned away in place first (rad)
TURN_FIRST_RAD = math.radians(25.0)
#: the approach ends this close to the docked pose along its axis (m)
STOP_M = 0.002
#: slowest forward speed of the approach (m/s) and the turn gain (1/s), the top turn (rad/s)
MIN_SPEED, TURN_GAIN, MAX_TURN = 0.015, 2.5, 0.6
#: each fit moves the estimate this much of the way (the newest revolutions count most)
BLEND = 0.25
#: the approach stops this far short to average the fits standing still (m)
SETTLE_M = 0.03
#: standing on the dock, the heading is turned to the dock's within this (rad)
ALIGN_RAD = math.radians(0.2)
#: the slowest turn of that alignment (rad/s)
MIN_TURN = 0.03


def approach_twist(robot: Pose2, docked: Pose2, speed: float) -> tuple[float, float, float]:
    """(linear m/s, angular rad/s, distance left m) for a robot at ``robot`` heading onto
    ``docked`` (both in one frame): along the dock's axis, steering onto it, slowing down to
    stop on the docked pose."""
    ex, ey, eth = between(docked, robot)
    remaining = -ex
    ref = -math.atan(ey / LOOKAHEAD_M)
    error = math.remainder(ref - eth, math.tau)
    if remaining <= STOP_M:
        return 0.0, 0.0, remaining
    if abs(error) > TURN_FIRST_RAD:
        return 0.0, max(-MAX_TURN, min(MAX_TURN, TURN_GAIN * error)), remaining
    w = max(-MAX_TURN, min(MAX_TURN, TURN_GAIN * error))
    v = max(MIN_SPEED, min(speed, 1.0 * remaining)) * math.cos(error)
    return v, w, remaining


def align_twist(robot: Pose2, docked: Pose2) -> float:
    """The turn in place (rad/s) that brings the heading onto the docked one; 0 when it is
    within :data:`ALIGN_RAD`."""
    error = math.remainder(docked[2] - robot[2], math.tau)
    if abs(error) <= ALIGN_RAD:
        return 0.0
    w = max(-MAX_TURN, min(MAX_TURN, TURN_GAIN * error))
    return math.copysign(max(abs(w), MIN_TURN), w)


def mean_pose(poses: list[Pose2]) -> Pose2:
    """The mean of poses (the headings' circular mean)."""
    n = len(poses)
    heading = math.atan2(sum(math.sin(p[2]) for p in poses), sum(math.cos(p[2]) for p in poses))
    return sum(p[0] for p in poses) / n, sum(p[1] for p in poses) / n, heading


@dataclass
class DockEstimate:
    """The docked pose in the odometry frame, blended over the fits of recent revolutions."""

    pose: Pose2 | None = None
    fits: int = 0
    last_fit: float = -math.inf
    #: the fits taken standing still (averaged instead of blended), or None
    still: list[Pose2] | None = None

    def add(self, fit: Pose2, now: float) -> None:
        self.fits += 1
        self.last_fit = now
        if self.still is not None:
            self.still.append(fit)
            return
        if self.fits == 1 or self.pose is None:  # the first fit replaces the guess
            self.pose = fit
            return
        x, y, theta = self.pose
        turn = math.remainder(fit[2] - theta, math.tau)
        self.pose = (x + BLEND * (fit[0] - x), y + BLEND * (fit[1] - y),
                     math.remainder(theta + BLEND * turn, math.tau))

    def reset(self, guess: Pose2 | None) -> None:
        self.pose, self.fits, self.last_fit, self.still = guess, 0, -math.inf, None

    def settle(self) -> int:
        """The pose becomes the mean of the fits taken since :attr:`still` was set (if any);
        how many there were."""
        still, self.still = self.still or [], None
        if still:
            self.pose = mean_pose(still)
        return len(still)
