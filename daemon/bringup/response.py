# test-motors: each wheel's lag behind a step command and its deceleration -> reaction_time_s.
from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivers import EncoderReading, MotorDriver

#: how long the wheels run at the test speed before the stop (s), and how often they are read
RUN_S = 0.6
SAMPLE_S = 0.01
#: the steady speed is the slope over this last part of the run (s)
STEADY_S = 0.3
#: the stop is over when a wheel has moved less than this in SETTLE_S (rad)
SETTLE_RAD, SETTLE_S = 0.005, 0.1
STOP_LIMIT_S = 2.0
#: added to the slowest lag measured, then rounded up to a multiple of ROUND_S (s)
MARGIN_S, ROUND_S = 0.05, 0.05


@dataclass(frozen=True)
class Wheel:
    """One wheel's response: steady speed (rad/s), the lag after the start and after the stop
    (s: the distance the wheel fell behind, or rolled on, over its speed) and the mean
    deceleration from the stop command until it was below a tenth of its speed (rad/s²)."""

    speed: float
    start_lag: float
    stop_lag: float
    deceleration: float


async def measure(driver: MotorDriver, speed: float) -> tuple[Wheel, Wheel] | None:
    """Step both wheels to ``speed``, then to zero, reading the encoders every
    :data:`SAMPLE_S`; None when the driver has no encoders or a wheel did not turn."""
    first = driver.read_encoders()
    if first is None:
        return None
    t_go = time.monotonic()
    await driver.set_wheel_speeds(speed, speed)
    try:
        run = await _sample(driver, lambda rs: rs[-1].t_mono - t_go >= RUN_S, RUN_S + 1.0,
                            (speed, speed))
        t_stop = time.monotonic()
        await driver.set_wheel_speeds(0.0, 0.0)
    finally:
        await driver.stop()
    stop = await _sample(driver, _settled_after(t_stop), STOP_LIMIT_S)
    wheels = [_wheel(side, first, run, stop, t_go, t_stop) for side in (0, 1)]
    if wheels[0] is None or wheels[1] is None:
        return None
    return wheels[0], wheels[1]


Done = Callable[[list[EncoderReading]], bool]


async def _sample(driver: MotorDriver, done: Done, limit_s: float,
                  hold: tuple[float, float] | None = None) -> list[EncoderReading]:
    """Encoder readings every :data:`SAMPLE_S` until ``done(readings)`` or ``limit_s``,
    re-sending ``hold`` each time (as the control loop does: it feeds a device's deadman)."""
    readings: list[EncoderReading] = []
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        await asyncio.sleep(SAMPLE_S)
        if hold is not None:
            await driver.set_wheel_speeds(*hold)
        reading = driver.read_encoders()
        if reading is None:
            break
        if not readings or reading.t_mono > readings[-1].t_mono:
            readings.append(reading)
        if readings and done(readings):
            break
    return readings


def _settled_after(t_stop: float) -> Done:
    def settled(readings: list[EncoderReading]) -> bool:
        last = readings[-1]
        old = [r for r in readings if r.t_mono <= last.t_mono - SETTLE_S and r.t_mono > t_stop]
        return bool(old) and max(abs(last.left_rad - old[-1].left_rad),
                                 abs(last.right_rad - old[-1].right_rad)) < SETTLE_RAD
    return settled


def _pos(reading: EncoderReading, side: int) -> float:
    return reading.left_rad if side == 0 else reading.right_rad


def _wheel(side: int, first: EncoderReading, run: list[EncoderReading],
           stop: list[EncoderReading], t_go: float, t_stop: float) -> Wheel | None:
    if len(run) < 3 or not stop:
        return None
    last = run[-1]
    steady = [r for r in run if r.t_mono >= last.t_mono - STEADY_S]
    if len(steady) < 2 or steady[-1].t_mono <= steady[0].t_mono:
        return None
    speed = (_pos(last, side) - _pos(steady[0], side)) / (last.t_mono - steady[0].t_mono)
    if abs(speed) < 1e-3:
        return None
    sign = math.copysign(1.0, speed)
    speed = abs(speed)
    moved = sign * (_pos(last, side) - _pos(first, side))
    start_lag = (last.t_mono - t_go) - moved / speed
    at_stop = sign * _pos(last, side) + speed * (t_stop - last.t_mono)  # still steady then
    stop_lag = (sign * _pos(stop[-1], side) - at_stop) / speed
    return Wheel(speed, max(0.0, start_lag), max(0.0, stop_lag),
                 _deceleration(side, sign, speed, last, stop, t_stop))


def _deceleration(side: int, sign: float, speed: float, last: EncoderReading,
                  stop: list[EncoderReading], t_stop: float) -> float:
    """Mean deceleration from the stop command until the wheel ran below a tenth of
    ``speed`` (speeds from consecutive readings)."""
    previous = last
    for reading in stop:
        dt = reading.t_mono - previous.t_mono
        if dt > 0 and reading.t_mono > t_stop:
            now = sign * (_pos(reading, side) - _pos(previous, side)) / dt
            if now < 0.1 * speed:
                return 0.9 * speed / max(reading.t_mono - t_stop, SAMPLE_S)
        previous = reading
    return 0.0


def recommended_reaction_s(wheels: tuple[Wheel, Wheel]) -> float:
    """``[collision_monitor] reaction_time_s`` for these wheels: the slowest lag, start or
    stop, plus :data:`MARGIN_S`, rounded up to :data:`ROUND_S`."""
    slowest = max(max(w.start_lag, w.stop_lag) for w in wheels)
    return round(math.ceil((slowest + MARGIN_S) / ROUND_S - 1e-9) * ROUND_S, 2)


def report(wheels: tuple[Wheel, Wheel] | None, wheel_radius: float) -> dict[str, Any]:
    """The ``response`` part of the test-motors report (decelerations in m/s² at the rim)."""
    if wheels is None:
        return {"measured": False}
    out: dict[str, Any] = {"measured": True}
    for name, w in zip(("left", "right"), wheels, strict=True):
        out[name] = {"speed_rad_s": round(w.speed, 3), "start_lag_s": round(w.start_lag, 3),
                     "stop_lag_s": round(w.stop_lag, 3),
                     "deceleration_m_s2": round(w.deceleration * wheel_radius, 2)}
    reaction = recommended_reaction_s(wheels)
    out["reaction_time_s"] = reaction
    out["lines"] = ["[collision_monitor]", f"reaction_time_s = {reaction:g}"]
    return out
