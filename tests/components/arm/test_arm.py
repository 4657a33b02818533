# The arm: kinematics by hand, and the contract over every servo backend against its emulator.
from __future__ import annotations

import math
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from base.options import defaults
from daemon.components.arm.controller import ArmController, ArmRefused
from daemon.components.arm.kinematics import forward
from daemon.components.arm.settings import SEED_POSES, ArmSettings
from drivers import pca9685_protocol as chip
from drivers.devices import create_device
from drivers.servo_array import ServoArray
from sim.wiring import DEVICE_EMULATORS

PERIOD = 1.0 / 50.0
JOINTS = ["arm_joint1", "arm_joint2", "arm_joint3", "gripper"]


# -- forward kinematics, against values worked out by hand -------------------------------------

# x = 0.10 + Σ Lᵢ sin(θ₁+…+θᵢ), z = 0.18 + Σ Lᵢ cos(θ₁+…+θᵢ), L = 0.200, 0.410, 0.200 m;
# e.g. pregrasp: sums 1.043, 1.977, 2.472 rad; sines 0.8640, 0.9187, 0.6209; cosines 0.5035,
# -0.3950, -0.7839: x = 0.10 + 0.1728 + 0.3767 + 0.1242, z = 0.18 + 0.1007 - 0.1620 - 0.1568.
HAND_COMPUTED = {
    "home": (0.100, 0.990, 0.0),
    "pregrasp": (0.7737, -0.0381, 2.472),
    "grasp": (0.5655, -0.2175, 3.232),
    "grasp_close": (0.5655, -0.2175, 3.232),
    "carry": (0.8469, 0.3872, 1.653),
}


@pytest.mark.parametrize("pose", sorted(SEED_POSES))
def test_forward_kinematics_of_the_seed_poses(pose: str) -> None:
    tip = forward(*SEED_POSES[pose][:3])
    x, z, pitch = HAND_COMPUTED[pose]
    assert (tip.x, tip.z, tip.pitch) == pytest.approx((x, z, pitch), abs=5e-4)


def test_full_reach_is_the_sum_of_the_links() -> None:
    tip = forward(math.pi / 2, 0.0, 0.0)
    assert (tip.x, tip.z) == pytest.approx((0.10 + 0.81, 0.18))


# -- the contract over the backends ------------------------------------------------------------


@dataclass
class Rig:
    arm: ArmController
    servo: ServoArray
    pulse: Any  # output => µs the emulator (or the mock) observed
    step_us: float
    estop: list[str]
    now: float = 0.0

    async def run(self, seconds: float) -> list[dict[str, float]]:
        """Step the servo rate in simulated time; the observed pulses after each step."""
        seen = []
        for _ in range(round(seconds / PERIOD)):
            self.now += PERIOD
            await self.arm.step(self.now)
            seen.append(self.pulses())
        return seen

    def pulses(self) -> dict[str, float]:
        return {j: self.pulse(out) for j, out in self.servo.outputs.items()}

    def expected(self, targets: dict[str, float]) -> dict[str, float]:
        return {j: self.servo.calibrations[j].pulse_us(v) for j, v in targets.items()}


def arm_settings(**over: Any) -> ArmSettings:
    return ArmSettings.from_values({**defaults(ArmSettings.OPTIONS), "enabled": True, **over})


BACKENDS = {"pigpio": "pigpio_servo", "pca9685": "pca9685_servo", "mock": "mock_servo"}


@pytest.fixture(params=sorted(BACKENDS))
async def rig(request: pytest.FixtureRequest, tmp_path: Path) -> AsyncIterator[Rig]:
    backend = request.param
    device = BACKENDS[backend]
    emulated = DEVICE_EMULATORS[device](tmp_path, {})
    settings = arm_settings(backend=backend, **emulated.options)
    servo = create_device(device, {k: getattr(settings, k) for k in ArmSettings.OPTIONS
                                   if hasattr(settings, k)}, section="arm")
    assert isinstance(servo, ServoArray)
    estop: list[str] = []
    arm = ArmController(settings, servo, 0.0, lambda: estop[-1] if estop else None)
    source: Any = emulated.emulator or servo
    step = chip.step_us(settings.frequency_hz) if backend == "pca9685" else 1.0
    await servo.open()
    try:
        yield Rig(arm, servo, source.servo_pulse_us, step, estop)
    finally:
        await servo.close()
        emulated.stop()


def close_within(observed: dict[str, float], expected: dict[str, float], step: float) -> bool:
    return all(abs(observed[j] - expected[j]) <= step for j in expected)


async def test_each_named_pose_is_reached(rig: Rig) -> None:
    await rig.arm.step(rig.now)
    assert close_within(rig.pulses(), rig.expected(rig.arm.poses["home"]), rig.step_us)
    for name in ("pregrasp", "grasp", "grasp_close", "carry", "home"):
        duration = rig.arm.go_to_pose(name, rig.now)
        await rig.run(duration + 2 * PERIOD)
        assert close_within(rig.pulses(), rig.expected(rig.arm.poses[name]), rig.step_us), name
        assert rig.arm.pose_at(rig.now) == name
        state = rig.arm.state(rig.now)
        assert state["pose"] == name and not state["moving"]


async def test_joints_arrive_together_at_the_slowest_joints_speed(rig: Rig) -> None:
    await rig.arm.step(rig.now)
    duration = rig.arm.go_to_pose("pregrasp", rig.now)
    assert duration == pytest.approx(1.043 / 1.0)  # joint1 has the farthest to go at 1 rad/s
    seen = await rig.run(duration + 3 * PERIOD)
    final = rig.expected(rig.arm.poses["pregrasp"])
    home = rig.expected(rig.arm.poses["home"])
    span = {j: final[j] - home[j] for j in final}
    for i, pulses in enumerate(seen):  # every joint the same fraction of its way, each step
        fractions = {j: (pulses[j] - home[j]) / span[j] for j in final}
        slack = {j: rig.step_us / abs(span[j]) for j in final}
        assert all(abs(fractions[j] - fractions["arm_joint1"]) <= slack[j] + slack["arm_joint1"]
                   for j in final), (i, fractions)
    arrived = [i for i, p in enumerate(seen) if close_within(p, final, rig.step_us)]
    assert arrived[0] == pytest.approx(duration / PERIOD, abs=1.5)  # at the slowest's speed


async def test_a_new_target_replaces_the_old_one_without_a_jump(rig: Rig) -> None:
    await rig.arm.step(rig.now)
    rig.arm.go_to_pose("carry", rig.now)
    before = (await rig.run(0.4))[-1]
    rig.arm.go_to_pose("home", rig.now)
    after = (await rig.run(PERIOD))[-1]
    assert all(abs(after[j] - before[j]) <= 1000 * 1.0 / 90 * 60 * PERIOD + rig.step_us
               for j in before)  # one step at 1 rad/s is 12.7 µs on a 2000 µs / π range


async def test_targets_outside_the_limits_are_refused_naming_the_joint(rig: Rig) -> None:
    await rig.arm.step(rig.now)
    with pytest.raises(ArmRefused, match=r"arm_joint2 = 2.0 is outside its limits") as err:
        rig.arm.command({"arm_joint2": 2.0}, rig.now)
    assert err.value.status == 422
    with pytest.raises(ArmRefused, match="gripper: expected a finite number"):
        rig.arm.command({"gripper": math.nan}, rig.now)
    with pytest.raises(ArmRefused, match="unknown joint 'wrist'"):
        rig.arm.command({"wrist": 0.0}, rig.now)
    with pytest.raises(ArmRefused, match="no pose named 'wave'; poses: home, pregrasp"):
        rig.arm.go_to_pose("wave", rig.now)
    assert not rig.arm.motion.moving(rig.now)


async def test_the_estop_freezes_the_arm_where_it_is(rig: Rig) -> None:
    await rig.arm.step(rig.now)
    rig.arm.go_to_pose("pregrasp", rig.now)
    await rig.run(0.3)
    rig.estop.append("test")
    frozen = (await rig.run(PERIOD))[-1]
    assert frozen != rig.expected(rig.arm.poses["home"])
    assert all(p == frozen for p in await rig.run(1.0))
    with pytest.raises(ArmRefused, match=r"e-stop engaged \(test\)") as err:
        rig.arm.go_to_pose("home", rig.now)
    assert err.value.status == 409
    rig.estop.clear()
    assert all(p == frozen for p in await rig.run(0.2))  # released: it stays until told
    rig.arm.go_to_pose("home", rig.now)
    await rig.run(1.0)
    assert close_within(rig.pulses(), rig.expected(rig.arm.poses["home"]), rig.step_us)


class FakeTime:
    """A clock that the shutdown's sleeps advance."""

    def __init__(self, now: float) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now

    async def sleep(self, seconds: float) -> None:
        self.now += seconds


async def test_shutdown_relaxes_the_servos_by_default(rig: Rig) -> None:
    await rig.arm.step(rig.now)
    rig.arm.go_to_pose("carry", rig.now)
    await rig.run(2.0)
    time = FakeTime(rig.now)
    assert await rig.arm.park_or_relax(time, time.sleep) == "relaxed"
    assert set(rig.pulses().values()) == {0.0}


async def test_shutdown_parks_at_home_when_configured(rig: Rig) -> None:
    rig.arm.settings = arm_settings(backend=rig.arm.settings.backend, on_stop="home")
    await rig.arm.step(rig.now)
    rig.arm.go_to_pose("carry", rig.now)
    await rig.run(2.0)
    rig.estop.append("shutdown")  # the daemon latches its own e-stop first
    await rig.run(PERIOD)
    time = FakeTime(rig.now)
    assert await rig.arm.park_or_relax(time, time.sleep) == "parked at home"
    assert close_within(rig.pulses(), rig.expected(rig.arm.poses["home"]), rig.step_us)


async def test_shutdown_after_a_users_estop_does_not_park(rig: Rig) -> None:
    rig.arm.settings = arm_settings(backend=rig.arm.settings.backend, on_stop="home")
    await rig.arm.step(rig.now)
    rig.arm.go_to_pose("carry", rig.now)
    await rig.run(0.3)
    rig.estop.append("operator")
    await rig.run(PERIOD)
    time = FakeTime(rig.now)
    assert await rig.arm.park_or_relax(time, time.sleep) == "relaxed"
