# Run-time check of the monitor's braking assumption: how far the odometry says each stop took.
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from daemon.components.collision_monitor.sweep import SCALE

#: a stop is judged only from at least this commanded speed (travel units per s)
MIN_SPEED = 0.5
#: the measured lag may exceed the assumed one by this much before it counts (s): odometry noise
TOLERANCE_S = 0.03
#: a stop that has not ended after this long is dropped (s)
LONGEST_STOP_S = 5.0
#: the wheels have come to rest this long after the command reached zero (s), plus three
#: assumed lags
SETTLE_S = 1.0


@dataclass
class Stop:
    """A stop in progress: when and where the command began to fall, from what speed, what the
    command has covered since, and when it reached zero."""

    t0: float
    pose: tuple[float, float, float]
    speed: float
    commanded_m: float = 0.0
    zero_at: float | None = None


class BrakingCheck:
    """Watches every stop from speed: the command ramps down, the wheels follow it some time
    behind. The distance the odometry shows beyond the commanded ramp, over the speed, is the
    measured lag; the monitor plans with ``assumed_lag`` (``reaction_time_s``). A lag beyond it
    means the robot brakes slower than the monitor assumes, and health says so."""

    def __init__(self, assumed_lag: float) -> None:
        self.assumed_lag = assumed_lag
        self.stops = 0
        self.slower = 0
        self.last: dict[str, Any] | None = None
        self.worst_lag = 0.0
        self._stop: Stop | None = None
        self._previous: tuple[float, float, tuple[float, float, float]] | None = None

    def observe(self, now: float, commanded: float,
                pose: tuple[float, float, float]) -> None:
        """One tick: the commanded path speed (travel units per s) and the odometry pose."""
        previous, self._previous = self._previous, (now, commanded, pose)
        if previous is None:
            return
        t_prev, cmd_prev, pose_prev = previous
        stop = self._stop
        if stop is None:
            if commanded < cmd_prev - 1e-9 and cmd_prev >= MIN_SPEED:
                stop = self._stop = Stop(t_prev, pose_prev, cmd_prev)
            else:
                return
        elif commanded > cmd_prev + 1e-9 or now - stop.t0 > LONGEST_STOP_S:
            self._stop = None  # sped up again: not a stop
            return
        stop.commanded_m += 0.5 * (commanded + cmd_prev) * (now - t_prev)
        if commanded != 0.0:
            return
        stop.zero_at = now if stop.zero_at is None else stop.zero_at
        if now - stop.zero_at >= SETTLE_S + 3.0 * self.assumed_lag:
            self._finish(stop, pose)

    def _finish(self, stop: Stop, pose: tuple[float, float, float]) -> None:
        self._stop = None
        self.stops += 1
        x, y, theta = stop.pose
        measured = math.hypot(math.hypot(pose[0] - x, pose[1] - y),
                              SCALE * _wrap(pose[2] - theta))
        lag = (measured - stop.commanded_m) / stop.speed
        self.worst_lag = max(self.worst_lag, lag)
        slower = lag > self.assumed_lag + TOLERANCE_S
        self.slower += slower
        self.last = {"from_speed": round(stop.speed, 3), "stopped_in_m": round(measured, 3),
                     "planned_m": round(stop.commanded_m + stop.speed * self.assumed_lag, 3),
                     "lag_s": round(lag, 3), "slower_than_assumed": slower}

    def reason(self) -> str | None:
        """Why health is degraded, or None while every stop was as fast as assumed."""
        if not self.slower:
            return None
        return (f"the robot brakes slower than the collision monitor assumes: {self.slower} of "
                f"{self.stops} stops lagged up to {self.worst_lag:.2f} s behind the command "
                f"(reaction_time_s = {self.assumed_lag:g}); measure the motors with `arbiterd "
                "test-motors` and raise [collision_monitor] reaction_time_s, or lower [limits] "
                "linear.x.emergency_deceleration (docs/safety.md)")

    def health(self, measured: bool) -> dict[str, Any]:
        return {"measured": measured, "assumed_lag_s": self.assumed_lag, "stops": self.stops,
                "slower_than_assumed": self.slower, "worst_lag_s": round(self.worst_lag, 3),
                "last": self.last}


def _wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))
