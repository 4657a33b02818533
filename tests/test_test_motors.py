# `arbiterd test-motors` against every emulator, with each [sim] miswire switch and none: the
# right diagnosis per side and the right fix lines (or wiring steps) every time.
from __future__ import annotations

import asyncio
import json
import math
import os
import select
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from daemon.bringup import cli as bringup_cli
from daemon.bringup.diagnosis import Spin, counts_per_rev_line, diagnose
from daemon.bringup.motors import NO_HAND_TURN
from daemon.config import Config, load_config
from sim.arduino_emulator import ArduinoEmulator
from sim.motor_model import MISWIRES, MotorPair, PairWiring
from tests.support.paths import REPO
from tests.support.wait import wait_for

HOST_LOOP = ("pigpio", "l298n")  # the speed loop (and the direction flags) on the host
SWAPPED_PINS = {
    "pigpio": ["left_pwm = 13", "right_pwm = 12", "left_in1 = 27", "right_in1 = 23",
               "left_in2 = 22", "right_in2 = 24"],
    "l298n": ["left_forward = 22", "right_forward = 17", "left_backward = 23",
              "right_backward = 18"],  # both enables jumpered (-1): nothing to swap
}


def config_for(tmp_path: Path, driver: str, miswire: list[str], extra: str = "") -> Config:
    path = tmp_path / f"{driver}-{'-'.join(miswire) or 'none'}.toml"
    path.write_text(f'[sim]\ndriver = "{driver}"\nmiswire = {json.dumps(miswire)}\n' + extra)
    return load_config(path, sim=True, env={})


async def run_in_sim(config: Config) -> dict[str, Any]:
    """What `arbiterd test-motors --sim --yes --json` prints, without a process of its own."""
    with bringup_cli.simulated_hardware(config) as pair:
        return await bringup_cli._test(config, bringup_cli.SimObserver(pair), pair)


def expected(driver: str, miswire: str | None) -> tuple[dict[str, str], list[str], str]:
    """(diagnosis per side, fix lines, a phrase of the wiring step) for one switch."""
    diagnoses = {"left": "ok", "right": "ok"}
    if miswire is None:
        return diagnoses, [], ""
    if miswire == "sides_swapped":
        pins = SWAPPED_PINS.get(driver, [])
        return ({"left": "sides_swapped", "right": "sides_swapped"},
                [f"[driver.{driver}]", *pins] if pins else [],
                "" if pins else "motors are on the wrong sides")
    side, part, fault = miswire.split("_")
    if fault == "dead":
        diagnoses[side] = "no_counts"
        return diagnoses, [], f"check the {side} encoder"
    diagnoses[side] = f"{part}_reversed"
    if driver in HOST_LOOP:
        return diagnoses, [f"[driver.{driver}]", f"{side}_{part}_inverted = true"], ""
    if driver == "serial":
        phrase = f"swap the {side} motor's two wires" if part == "motor" else \
            f"swap the {side} encoder's A and B wires"
        return diagnoses, [], phrase
    return diagnoses, [], f"ODrive's {side} axis turns against its encoder"


@pytest.mark.parametrize("driver", ["serial", "pigpio", "l298n", "odrive_can"])
async def test_each_miswiring_is_diagnosed_with_its_fix(driver: str, tmp_path: Path) -> None:
    cases: list[str | None] = [None, *MISWIRES]
    configs = [config_for(tmp_path, driver, [case] if case else []) for case in cases]
    results = await asyncio.gather(*(run_in_sim(config) for config in configs))
    for case, result in zip(cases, results, strict=True):
        diagnoses, fix, rewire = expected(driver, case)
        seen = {side: result[side]["diagnosis"] for side in ("left", "right")}
        assert seen == diagnoses, (case, result)
        assert result["fix"] == fix, (case, result)
        if rewire:
            assert any(rewire in step for step in result["rewire"]), (case, result)
        else:
            assert result["rewire"] == [], (case, result)
        assert result["ok"] is (case is None)
        if driver not in NO_HAND_TURN and case not in ("left_encoder_dead", "sides_swapped"):
            assert result["left"]["counts_per_rev"] == pytest.approx(
                result["left"]["counts_per_rev_config"], rel=0.02), result


async def test_a_mirrored_motor_and_encoder_is_fixed_by_both_flags(tmp_path: Path) -> None:
    """Motor and encoder agree but both run backward: the firmware's PID is happy and only the
    hand turn shows the wheel goes the wrong way; the host flags fix it even in closed loop."""
    config = config_for(tmp_path, "serial", ["right_motor_reversed", "right_encoder_reversed"])
    result = await run_in_sim(config)
    assert result["right"]["diagnosis"] == "motor_reversed"
    assert result["fix"] == ["[driver.serial]", "right_motor_inverted = true",
                             "right_encoder_inverted = true"]
    assert result["left"]["diagnosis"] == "ok" and result["rewire"] == []


async def test_a_driver_without_encoders_says_what_to_watch(tmp_path: Path) -> None:
    config = config_for(tmp_path, "mock", [], "[driver.mock]\nencoders = false\n")
    result = await run_in_sim(config)
    assert result["left"]["diagnosis"] == result["right"]["diagnosis"] == "open_loop"
    assert result["fix"] == [] and any("backward" in item for item in result["watch"])


def test_the_command_line_prints_one_json_object(tmp_path: Path) -> None:
    path = tmp_path / "m.toml"
    path.write_text('[sim]\ndriver = "pigpio"\nmiswire = ["right_motor_reversed"]\n')
    done = subprocess.run([sys.executable, "-m", "daemon.cli", "test-motors", "--config",
                           str(path), "--sim", "--yes", "--json"], capture_output=True,
                          text=True, cwd=REPO, timeout=120)
    assert done.returncode == 1, done.stderr
    result = json.loads(done.stdout)
    assert result["right"]["diagnosis"] == "motor_reversed"
    assert result["fix"] == ["[driver.pigpio]", "right_motor_inverted = true"]


def test_it_asks_before_spinning_the_wheels(tmp_path: Path) -> None:
    path = tmp_path / "m.toml"
    path.write_text('[sim]\ndriver = "mock"\n')
    done = subprocess.run([sys.executable, "-m", "daemon.cli", "test-motors", "--config",
                           str(path), "--sim"], input="n\n", capture_output=True, text=True,
                          cwd=REPO, timeout=60)
    assert done.returncode == 1
    assert "Are both wheels off the ground?" in done.stderr
    assert "not confirmed" in done.stderr and done.stdout == ""


def test_unwatched_on_hardware_the_encoder_is_blamed_and_the_note_says_so(
        tmp_path: Path) -> None:
    """No terminal (stdin is a pipe) and no --sim: a board whose left encoder counts backward
    is reported against the command, with a note that nobody checked the direction."""
    pair = MotorPair(wiring=PairWiring.build(miswire=["left_encoder_reversed"]))
    pair.left.counts_per_rev = pair.right.counts_per_rev = 1440
    with ArduinoEmulator(tmp_path / "arduino", pair, boot_s=0.0):
        path = tmp_path / "hw.toml"
        path.write_text(f'[driver]\ntype = "serial"\n[driver.serial]\nport = '
                        f'"{tmp_path / "arduino"}"\nreset_wait_s = 0.05\nmode = "open_loop"\n'
                        f'full_pwm_speed = 40.0\n')
        done = subprocess.run([sys.executable, "-m", "daemon.cli", "test-motors", "--config",
                               str(path), "--yes", "--json"], stdin=subprocess.DEVNULL,
                              capture_output=True, text=True, cwd=REPO, timeout=60)
    result = json.loads(done.stdout)
    assert result["left"]["diagnosis"] == "encoder_reversed", result
    assert any("nobody watched" in note for note in result["left"]["notes"])
    assert result["fix"] == ["[driver.serial]", "left_encoder_inverted = true"]
    assert result["right"]["diagnosis"] == "ok"


def test_a_wrong_counts_per_rev_gets_its_line() -> None:
    measured, configured, line = counts_per_rev_line("serial", {"counts_per_rev": 1440},
                                                     2 * math.pi * 4096 / 1440)
    assert (round(measured), configured, line) == (4096, 1440, {"counts_per_rev": 4096})
    assert counts_per_rev_line("serial", {"counts_per_rev": 1440}, 2 * math.pi)[2] == {}


def test_a_wheel_that_does_not_turn_is_not_blamed_on_the_encoder() -> None:
    finding = diagnose("left", Spin(3.0, 0.0, 0.0), 2 * math.pi)
    assert finding.diagnosis == "no_counts" and "did not turn the wheel" in finding.notes[0]


def read_until(fd: int, text: str, seen: bytearray, within_s: float = 20.0) -> None:
    """Read the terminal's output until ``text`` appears (after what was already matched)."""

    def appeared() -> bool:
        if text.encode() in seen:
            return True
        if select.select([fd], [], [], 0.1)[0]:
            seen.extend(os.read(fd, 4096))
        return False

    wait_for(appeared, lambda: f"{text!r} on the terminal: {bytes(seen)!r}", within_s=within_s,
             interval_s=0)
    del seen[:seen.index(text.encode()) + len(text)]


def test_at_a_terminal_a_person_turns_the_wheels_by_hand(tmp_path: Path) -> None:
    """The interactive path on "hardware" (an emulated Arduino in closed loop whose left motor
    is wired backwards): the person confirms, turns each wheel one revolution when asked, and
    gets the diagnosis; no setting can fix a motor against its encoder under the firmware's
    PID, so it says which wires to swap."""
    pair = MotorPair(wiring=PairWiring.build(miswire=["left_motor_reversed"]))
    pair.left.counts_per_rev = pair.right.counts_per_rev = 1440
    master, slave = os.openpty()
    with ArduinoEmulator(tmp_path / "arduino", pair):
        path = tmp_path / "hw.toml"
        path.write_text(f'[driver]\ntype = "serial"\n[driver.serial]\nport = '
                        f'"{tmp_path / "arduino"}"\nreset_wait_s = 0.05\n')
        proc = subprocess.Popen([sys.executable, "-m", "daemon.cli", "test-motors", "--config",
                                 str(path), "--json"], stdin=slave, stderr=slave,
                                stdout=subprocess.PIPE, text=True, cwd=REPO)
        os.close(slave)
        try:
            seen = bytearray()
            read_until(master, "Are both wheels off the ground? [y/N] ", seen)
            os.write(master, b"y\n")
            for index, side in enumerate(("LEFT", "RIGHT")):
                read_until(master, f"Mark the {side} tyre", seen)
                read_until(master, "(s to skip): ", seen)
                pair.turn_by_hand(index, 2 * math.pi)
                os.write(master, b"\n")
            out, _ = proc.communicate(timeout=30)
        finally:
            proc.kill()
            os.close(master)
    result = json.loads(out)
    assert result["left"]["diagnosis"] == "motor_reversed", result
    assert result["left"]["counts_per_rev"] == pytest.approx(1440, rel=0.02)
    assert result["right"]["diagnosis"] == "ok" and result["fix"] == []
    assert any("swap the left motor's two wires" in step for step in result["rewire"])


async def test_the_step_response_sets_the_reaction_budget(tmp_path: Path) -> None:
    """Slow hobby gear motors (0.25 s time constant) and the simulated default (0.05 s): the
    measured lag and the reaction_time_s line that follows from it (docs/safety.md)."""
    configs = []
    for name, tau in (("slow", 0.25), ("fast", 0.05)):
        (tmp_path / name).mkdir()
        configs.append(config_for(tmp_path / name, "serial", [],
                                  f"motor_time_constant = {tau}\n"))
    slow, fast = await asyncio.gather(*(run_in_sim(config) for config in configs))
    for result, tau in ((slow, 0.25), (fast, 0.05)):
        response = result["response"]
        assert response["measured"], result
        for side in ("left", "right"):
            assert response[side]["stop_lag_s"] == pytest.approx(tau, abs=0.05), response
        assert response["reaction_time_s"] >= tau + 0.05, response
        assert response["lines"] == ["[collision_monitor]",
                                     f"reaction_time_s = {response['reaction_time_s']:g}"]
    assert slow["response"]["reaction_time_s"] <= 0.4
    assert fast["response"]["reaction_time_s"] <= 0.2
