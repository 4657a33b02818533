# One contract test for every registered driver, each through the real control loop against
# the emulator that speaks its protocol: forward, reverse, turn in place, stop, deadman stop.
# Also: every registered driver has an emulator wiring, a rig and docs, and reads its options.
from __future__ import annotations

import asyncio
import re
import time
import tomllib
from dataclasses import fields
from pathlib import Path
from typing import Any

import pytest

from daemon.bus import Bus
from daemon.commands import Twist
from daemon.components.control.kinematics import DiffDrive
from daemon.components.control.loop import ControlLoop
from daemon.config import build_driver, load_config
from daemon.latency import LatencyTracker
from daemon.settings import DriverSettings
from drivers import DRIVERS, create_driver
from sim.settings import SimSettings
from sim.wiring import EMULATORS
from tests.support.compare import close_to
from tests.support.paths import REPO
from tests.support.rigs import RIGS, Rig
from tests.support.wait import eventually

TIMEOUT_S = 0.4
GEOMETRY = DiffDrive(wheel_separation=0.30, wheel_radius=0.05)
MOVES = [
    ("forward", Twist(0.3, 0.0)),
    ("reverse", Twist(-0.3, 0.0)),
    ("turn in place", Twist(0.0, 1.0)),
    ("arc", Twist(0.2, -0.5)),
    ("stop", Twist(0.0, 0.0)),
]


# -- the registry is the one list ----------------------------------------------------------


def test_the_config_choices_are_the_registered_drivers() -> None:
    assert DriverSettings.OPTIONS["type"].choices == tuple(DRIVERS)
    assert SimSettings.OPTIONS["driver"].choices == tuple(DRIVERS)
    assert sorted(EMULATORS) == sorted(DRIVERS), "one row in sim/wiring.py EMULATORS per driver"


@pytest.mark.parametrize("name", sorted(DRIVERS))
def test_every_registered_driver_has_an_emulator_a_rig_and_docs(name: str) -> None:
    assert name in EMULATORS, f"add {name!r} to EMULATORS in sim/wiring.py"
    assert name in RIGS, f"add a rig for {name!r} to tests/rigs"
    guide = (REPO / "docs" / "adding-a-driver.md").read_text()
    documented = (REPO / "docs" / f"driver-{name}.md").exists() or \
        re.search(rf"^## .*`{name}`", guide, re.MULTILINE) is not None
    assert documented, f"write docs/driver-{name}.md (or a section in docs/adding-a-driver.md)"


@pytest.mark.parametrize("name", sorted(DRIVERS))
def test_a_driver_reads_its_options_once_into_typed_settings(name: str) -> None:
    driver = create_driver(name, {}, max_wheel_speed=1.0)
    assert driver.name() == name
    assert {f.name for f in fields(driver.settings)} == set(driver.OPTIONS)
    assert all(getattr(driver.settings, key) == option.default
               for key, option in driver.OPTIONS.items())
    with pytest.raises(ValueError, match=rf"\[driver\.{name}\] unknown option\(s\): no_such_key"):
        create_driver(name, {"no_such_key": 1}, max_wheel_speed=1.0)


def test_every_drivers_module_is_a_pure_protocol_or_kept_from_sim() -> None:
    """A new module under drivers/ must be classified in pyproject.toml: a pure protocol
    module (sim/ may import it) or one with I/O (forbidden to sim/)."""
    contracts = {c["id"]: c for c in tomllib.loads(
        (REPO / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]}
    pure = set(contracts["pure-protocols"]["source_modules"])
    kept_from_sim = set(contracts["sim-uses-protocols-only"]["forbidden_modules"])
    modules = {f"drivers.{path.stem}" for path in (REPO / "drivers").glob("*.py")
               if path.stem != "__init__"}
    assert modules - pure - kept_from_sim == set()
    assert pure & kept_from_sim == set()


# -- the contract ----------------------------------------------------------------------------


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
    config.update(f"driver.{driver_name}", options)
    return ControlLoop(config, build_driver(config), Bus(), LatencyTracker())


async def hold_until(loop: ControlLoop, rig: Rig, twist: Twist, expected: tuple[float, float],
                     tolerance: float, limit_s: float = 5.0) -> tuple[float, float]:
    """Keep commanding ``twist`` (as a teleop would) until the hardware sees ``expected``."""
    seen = (float("nan"), float("nan"))

    async def command_then_seen() -> tuple[float, float] | None:
        nonlocal seen
        applied = await loop.submit("contract", twist, t_recv=time.monotonic())
        assert applied.accepted, applied.error
        await asyncio.sleep(0.05)
        seen = rig.observed_targets()
        return seen if close_to(seen, expected, tolerance) else None

    held: tuple[float, float] = await eventually(
        command_then_seen, lambda: f"the hardware to see {expected} ± {tolerance}; it saw {seen}",
        within_s=limit_s, interval_s=0)
    return held


async def test_driver_contract(rig: Rig, tmp_path: Path) -> None:
    loop = make_loop(rig.driver_name, rig.options, tmp_path)
    tolerance = max(rig.quantum_rad_s * 1.5, 0.05)
    await loop.start()
    try:
        for name, twist in MOVES:
            expected = GEOMETRY.wheel_speeds(twist.linear_x, twist.angular_z)
            seen = await hold_until(loop, rig, twist, expected, tolerance)
            assert seen == pytest.approx(expected, abs=tolerance), name
        await hold_until(loop, rig, Twist(0.4, 0.0), GEOMETRY.wheel_speeds(0.4, 0.0), tolerance)
        start = time.monotonic()
        await eventually(lambda: close_to(rig.observed_targets(), (0.0, 0.0), tolerance),
                         "the deadman stop", within_s=TIMEOUT_S + 2.0)
        assert time.monotonic() - start <= TIMEOUT_S + 0.5, "deadman stop too late"
        assert loop.decision.reason in ("deadman: no valid command", "idle")
        assert loop.fault is None and loop.driver.health()["status"] == "ok"
        assert loop.wheel_guard.trips == 0, loop.wheel_guard.tripped  # no false wheel-mismatch stop
    finally:
        await loop.stop()
    assert close_to(rig.observed_targets(), (0.0, 0.0), tolerance)
    assert loop.driver.is_closed
