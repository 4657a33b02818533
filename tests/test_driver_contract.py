# One contract test for every registered driver, each through the real control loop against
# the emulator that speaks its protocol: forward, reverse, turn in place, stop, deadman stop.
from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import pytest

from daemon.bus import Bus
from daemon.config import load_config
from daemon.control.commands import Twist
from daemon.control.kinematics import DiffDrive
from daemon.control.loop import ControlLoop
from daemon.latency import LatencyTracker
from daemon.probe import build_driver
from drivers import DRIVERS
from tests.rigs import RIGS, rig_factory

TIMEOUT_S = 0.4
GEOMETRY = DiffDrive(wheel_separation=0.30, wheel_radius=0.05)
MOVES = [
    ("forward", Twist(0.3, 0.0)),
    ("reverse", Twist(-0.3, 0.0)),
    ("turn in place", Twist(0.0, 1.0)),
    ("arc", Twist(0.2, -0.5)),
    ("stop", Twist(0.0, 0.0)),
]


def test_every_registered_driver_has_a_rig() -> None:
    missing = [name for name in DRIVERS if not any(r.split("@")[0] == name for r in RIGS)]
    assert missing == []


def make_loop(driver_name: str, options: dict[str, Any], tmp_path: Path) -> ControlLoop:
    toml = tmp_path / "contract.toml"
    toml.write_text(f"""
[driver]
type = "{driver_name}"
[control]
cmd_vel_timeout = {TIMEOUT_S}
[limits]
linear.x.max_acceleration = 100.0
linear.x.max_deceleration = 100.0
linear.x.emergency_deceleration = 100.0
angular.z.max_acceleration = 100.0
angular.z.max_deceleration = 100.0
angular.z.emergency_deceleration = 100.0
""")
    config = load_config(toml, env={})
    config.sections[f"driver.{driver_name}"].update(options)
    return ControlLoop(config, build_driver(config), Bus(), LatencyTracker())


async def hold_until(loop: ControlLoop, rig: Any, twist: Twist, expected: tuple[float, float],
                     tolerance: float, limit_s: float = 5.0) -> tuple[float, float]:
    """Keep commanding ``twist`` (as a teleop would) until the hardware sees ``expected``."""
    deadline = time.monotonic() + limit_s
    seen = (float("nan"), float("nan"))
    while time.monotonic() < deadline:
        applied = await loop.submit("contract", twist, t_recv=time.monotonic())
        assert applied.accepted, applied.error
        await asyncio.sleep(0.05)
        seen = rig.observed_targets()
        if all(abs(s - e) <= tolerance for s, e in zip(seen, expected, strict=True)):
            return seen
    raise AssertionError(f"hardware saw {seen}, expected {expected} ± {tolerance}")


async def wait_still(rig: Any, tolerance: float, limit_s: float) -> float:
    start = time.monotonic()
    while time.monotonic() - start < limit_s:
        if all(abs(s) <= tolerance for s in rig.observed_targets()):
            return time.monotonic() - start
        await asyncio.sleep(0.01)
    raise AssertionError(f"wheels still turning: {rig.observed_targets()}")


@pytest.mark.parametrize("rig_name", sorted(RIGS))
async def test_driver_contract(rig_name: str, tmp_path: Path) -> None:
    async with rig_factory(rig_name)(tmp_path) as rig:
        loop = make_loop(rig.driver_name, rig.options, tmp_path)
        if hasattr(rig, "driver"):
            rig.driver = loop.driver
        tolerance = max(getattr(rig, "tolerance_rad_s", 0.0),
                        getattr(rig, "quantum_rad_s", 0.0) * 1.5, 0.05)
        await loop.start()
        try:
            for name, twist in MOVES:
                expected = GEOMETRY.wheel_speeds(twist.linear_x, twist.angular_z)
                seen = await hold_until(loop, rig, twist, expected, tolerance)
                assert seen == pytest.approx(expected, abs=tolerance), name
            await hold_until(loop, rig, Twist(0.4, 0.0), GEOMETRY.wheel_speeds(0.4, 0.0),
                             tolerance)
            stopped_after = await wait_still(rig, tolerance, TIMEOUT_S + 2.0)
            assert stopped_after <= TIMEOUT_S + 0.5, "deadman stop too late"
            assert loop.decision.reason in ("deadman: no valid command", "idle")
            assert loop.fault is None and loop.driver.health()["status"] == "ok"
        finally:
            await loop.stop()
        assert all(abs(s) <= tolerance for s in rig.observed_targets())
        assert loop.driver.is_closed
