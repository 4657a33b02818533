# `arbiterd test-motors`: turn each wheel by hand, spin it alone, then both; report and fix lines.
from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

from daemon.bringup import response
from daemon.bringup.diagnosis import (
    SIDES,
    Finding,
    Spin,
    counts_per_rev_line,
    diagnose,
    fixes_for,
)
from drivers import EncoderReading, MotorDriver

#: how fast a wheel spins during the test: half a turn per second (or half the clamp)
SPIN_RAD_S = math.pi
SPIN_S = 1.0
#: a wheel faster than this many times the asked speed is running away: stop at once
RUNAWAY_FACTOR = 3.0
SAMPLE_S = 0.05
#: drivers whose wheels hold still at zero (the speed loop runs in the device) or that have no
#: wheels to turn: the wheel's direction is watched during the spin instead of turned by hand
NO_HAND_TURN = ("odrive_can", "mock")


class Observer(Protocol):
    """Who moves and watches the wheels: a person at a terminal, or the simulation."""

    def turn_by_hand(self, side: str) -> bool:
        """Have the wheel turned one revolution forward by hand; False when nobody can."""

    def watch(self, side: str) -> None:
        """A spin of ``side`` starts now."""

    def watched(self, side: str) -> int | None:
        """After the spin: which way the wheel turned (1, -1, 0), or None when unwatched."""


@dataclass(frozen=True)
class Step:
    """One spin: what was asked for and what each encoder counted (rad)."""

    commanded: tuple[float, float]
    moved: tuple[float, float]
    seconds: float
    runaway: bool


async def run(driver: MotorDriver, options: Mapping[str, Any], observer: Observer,
              wheel_radius: float = 0.05) -> dict[str, Any]:
    """The whole test on an opened driver; returns the report (see :func:`report`), with the
    wheels' step response (``response``) when they are well."""
    speed = min(SPIN_RAD_S, 0.5 * driver.max_wheel_speed)
    if driver.read_encoders() is None:
        steps = {name: await spin(driver, wheels, speed) for name, wheels in _plan()}
        return open_loop_report(driver.name(), steps)
    hand = {}
    if driver.name() not in NO_HAND_TURN:
        for side in SIDES:
            hand[side] = await hand_turn(driver, observer, side)
    steps, spins = {}, {}
    for index, side in enumerate(SIDES):
        observer.watch(side)
        step = steps[side] = await spin(driver, _alone(index), speed)
        seen = await asyncio.to_thread(observer.watched, side)
        spins[side] = Spin(step.commanded[index] * step.seconds, step.moved[index],
                           step.moved[1 - index], seen)
    steps["both"] = await spin(driver, (1.0, 1.0), speed)
    findings = [diagnose(side, spins[side], hand.get(side)) for side in SIDES]
    out = report(driver.name(), options, findings, spins, hand, steps)
    wheels = await response.measure(driver, speed) if out["ok"] else None
    out["response"] = response.report(wheels, wheel_radius)
    return out


def _plan() -> list[tuple[str, tuple[float, float]]]:
    return [("left", (1.0, 0.0)), ("right", (0.0, 1.0)), ("both", (1.0, 1.0))]


def _alone(index: int) -> tuple[float, float]:
    return (1.0, 0.0) if index == 0 else (0.0, 1.0)


async def settled(driver: MotorDriver, after: float, limit_s: float = 2.0) -> EncoderReading:
    """An encoder reading taken after ``after`` that stays put for 0.1 s (wheels at rest)."""
    deadline = time.monotonic() + limit_s
    last = await _reading(driver)
    while time.monotonic() < deadline:
        await asyncio.sleep(0.1)
        now = await _reading(driver)
        if now.t_mono > after and (now.left_rad, now.right_rad) == (last.left_rad,
                                                                    last.right_rad):
            return now
        last = now
    return last


async def _reading(driver: MotorDriver) -> EncoderReading:
    reading = driver.read_encoders()
    assert reading is not None  # only called on drivers with encoders
    return reading


async def hand_turn(driver: MotorDriver, observer: Observer, side: str) -> float | None:
    """Encoder travel of ``side`` (rad, as configured) for one forward turn by hand."""
    index = SIDES.index(side)
    before = await settled(driver, time.monotonic())
    if not await asyncio.to_thread(observer.turn_by_hand, side):
        return None
    after = await settled(driver, time.monotonic())
    return (after.left_rad, after.right_rad)[index] - (before.left_rad, before.right_rad)[index]


async def spin(driver: MotorDriver, wheels: tuple[float, float], speed: float) -> Step:
    """Drive ``wheels`` (fractions of ``speed``) for :data:`SPIN_S`, stop, let them settle."""
    commanded = (wheels[0] * speed, wheels[1] * speed)
    before = await settled(driver, time.monotonic()) if driver.read_encoders() else None
    start = time.monotonic()
    runaway = False
    try:
        await driver.set_wheel_speeds(*commanded)
        while time.monotonic() - start < SPIN_S and not runaway:
            await asyncio.sleep(SAMPLE_S)
            await driver.set_wheel_speeds(*commanded)  # as the control loop would: it feeds
            # the device's deadman (the pigpio driver's script, the ODrive's watchdog)
            runaway = before is not None and _running_away(await _reading(driver), before,
                                                           start, speed)
    finally:
        await driver.stop()
    seconds = time.monotonic() - start
    if before is None:
        return Step(commanded, (0.0, 0.0), seconds, False)
    after = await settled(driver, time.monotonic())
    moved = (after.left_rad - before.left_rad, after.right_rad - before.right_rad)
    return Step(commanded, moved, seconds, runaway)


def _running_away(now: EncoderReading, before: EncoderReading, start: float,
                  speed: float) -> bool:
    elapsed = max(time.monotonic() - start, SAMPLE_S)
    fastest = max(abs(now.left_rad - before.left_rad), abs(now.right_rad - before.right_rad))
    return fastest / elapsed > RUNAWAY_FACTOR * speed + 1.0


# -- reports -----------------------------------------------------------------------------------


def report(driver: str, options: Mapping[str, Any], findings: list[Finding],
           spins: dict[str, Spin], hand: dict[str, float | None],
           steps: dict[str, Step]) -> dict[str, Any]:
    """The JSON report: ``left``/``right`` each with a ``diagnosis`` and figures, ``both``,
    ``fix`` (config lines, empty when all is well) and ``rewire`` (steps no setting can do)."""
    fixes = fixes_for(driver, options, findings)
    out: dict[str, Any] = {"driver": driver}
    for finding in findings:
        side = finding.side
        out[side] = _side(driver, options, finding, spins[side], hand.get(side),
                          steps[side], fixes.lines)
    both = steps["both"]
    out["both"] = {"commanded_rad_s": list(both.commanded),
                   "measured_rad_s": [round(m / both.seconds, 3) for m in both.moved]}
    out["fix"] = fixes.config_lines(f"driver.{driver}")
    out["rewire"] = fixes.rewire
    out["ok"] = not out["fix"] and not fixes.rewire and all(
        f.diagnosis == "ok" for f in findings)
    return out


def _side(driver: str, options: Mapping[str, Any], finding: Finding, spin_: Spin,
          hand_rad: float | None, step: Step, lines: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {
        "diagnosis": finding.diagnosis,
        "commanded_rad_s": round(spin_.commanded_rad / step.seconds, 3),
        "measured_rad_s": round(spin_.own_rad / step.seconds, 3),
        "other_side_rad_s": round(spin_.other_rad / step.seconds, 3),
        "ran_away": step.runaway,
        "watched": spin_.watched,
        "hand_turn_rad": None if hand_rad is None else round(hand_rad, 4),
        "counts_per_rev": None, "counts_per_rev_config": None,
        "notes": finding.notes,
    }
    if hand_rad is not None and finding.diagnosis not in ("no_counts",):
        measured, configured, line = counts_per_rev_line(driver, options, hand_rad)
        out["counts_per_rev"] = round(measured, 1)
        out["counts_per_rev_config"] = configured
        lines.update(line)
    out["fix"] = [f"{k} = {_value(v)}" for k, v in lines.items() if k.startswith(finding.side)]
    return out


def _value(value: Any) -> str:
    return ("true" if value else "false") if isinstance(value, bool) else str(value)


def open_loop_report(driver: str, steps: dict[str, Step]) -> dict[str, Any]:
    """Without encoders nothing can be measured: say what to watch for."""
    watch = [
        "the left wheel alone turned first, then the right alone, then both together",
        "each turned forward (the way that drives the robot forward); one that turned "
        "backward needs <side>_motor_inverted = true",
        "if the right wheel turned when the left should have, the motors are on the wrong "
        "sides: swap their connectors (or the pins of the two sides)",
    ]
    out: dict[str, Any] = {"driver": driver}
    for side in SIDES:
        step = steps[side]
        out[side] = {"diagnosis": "open_loop", "commanded_rad_s": list(step.commanded),
                     "fix": [], "notes": ["no encoders: watch the wheels"]}
    out["both"] = {"commanded_rad_s": list(steps["both"].commanded)}
    out.update(fix=[], rewire=[], watch=watch, ok=True)
    return out


def render(result: dict[str, Any]) -> str:
    """The human summary of a report."""
    lines = [f"test-motors on the {result['driver']} driver:"]
    for side in SIDES:
        info = result[side]
        figures = ""
        if "measured_rad_s" in info:
            figures = (f"  asked {info['commanded_rad_s']:+.2f} rad/s, encoder "
                       f"{info['measured_rad_s']:+.2f} rad/s (other side "
                       f"{info['other_side_rad_s']:+.2f})")
            if info.get("counts_per_rev") is not None:
                figures += (f"; {info['counts_per_rev']:.0f} counts per wheel revolution "
                            f"(config {info['counts_per_rev_config']})")
        lines.append(f"  {side:<5} {info['diagnosis']}{figures}")
        lines += [f"        {note}" for note in info.get("notes", [])]
    for item in result.get("watch", []):
        lines.append(f"  watch: {item}")
    if result["fix"]:
        lines.append("put these lines in the config file:")
        lines += [f"    {line}" for line in result["fix"]]
    for step in result["rewire"]:
        lines.append(f"  rewire: {step}")
    if result["ok"] and "watch" not in result:
        lines.append("all is well: the motors and encoders agree")
    lines += _render_response(result.get("response", {}))
    return "\n".join(lines)


def _render_response(info: dict[str, Any]) -> list[str]:
    if not info.get("measured"):
        return []
    lines = ["step response (both wheels, then a stop):"]
    for side in SIDES:
        w = info[side]
        lines.append(f"  {side:<5} {w['speed_rad_s']:.2f} rad/s; lags {w['start_lag_s']:.3f} s "
                     f"starting, {w['stop_lag_s']:.3f} s stopping; slowed at "
                     f"{w['deceleration_m_s2']:.2f} m/s² from this speed, unloaded")
    lines.append("the collision monitor's reaction budget for these motors (docs/safety.md):")
    lines += [f"    {line}" for line in info["lines"]]
    return lines
