# [arm]: the servo backend, each joint's output, limits, calibration and speed, and the named poses.
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from base.config import SectionSettings
from base.options import option
from drivers.i2c_link import check_bus
from drivers.pca9685_protocol import DEFAULT_ADDRESS
from drivers.servo_array import (
    JOINT_MAX_PULSE_US,
    JOINT_MIN_PULSE_US,
    MAX_PULSE_US,
    MIN_PULSE_US,
    OFFSETS_US,
    REVERSED,
)
from drivers.servo_pulses import SERVO_HZ

JOINT_COUNT = 4  # three pitching joints, then the gripper
HALF_PI = round(math.pi / 2, 6)
#: backend => the device (drivers/device_registry.py) it is
BACKENDS = {"pigpio": "pigpio_servo", "pca9685": "pca9685_servo", "mock": "mock_servo"}

#: the seed's named poses: joint1, joint2, joint3 (rad), gripper opening (m)
SEED_POSES: dict[str, tuple[float, float, float, float]] = {
    "home": (0.0, 0.0, 0.0, 0.0),
    "pregrasp": (1.043, 0.934, 0.495, 0.035),
    "grasp": (1.156, 1.163, 0.913, 0.035),
    "grasp_close": (1.156, 1.163, 0.913, 0.0),
    "carry": (0.827, 0.527, 0.299, 0.0),
}


def pose_entry_problem(value: Any) -> str | None:
    """Why one ``poses`` entry is not ``[name, j1, j2, j3, gripper_m]`` (the whole list
    passes: its entries are checked one by one)."""
    if isinstance(value, list) and value and all(isinstance(v, list) for v in value):
        return None
    if not isinstance(value, list) or len(value) != 1 + JOINT_COUNT \
            or not isinstance(value[0], str) or not value[0]:
        return f"expected [name, joint1, joint2, joint3, gripper_m], got {value!r}"
    for number in value[1:]:
        if isinstance(number, bool) or not isinstance(number, int | float) \
                or not math.isfinite(number):
            return f"pose {value[0]!r}: expected finite numbers, got {number!r}"
    return None


@dataclass(frozen=True)
class ArmSettings(SectionSettings, section="arm"):
    """The [arm] section, read once. The servo calibration keys the devices share are declared
    in drivers/servo_array.py; the device reads its own keys from this section."""

    enabled: bool = option(False, "drive the arm and gripper servos")
    backend: str = option("mock", "servo output: pigpio (pigpiod's servo pulses on GPIO pins), "
                          "pca9685 (a PCA9685 board over I2C) or mock (records)",
                          choices=tuple(BACKENDS))
    host: str = option("localhost", "pigpio: the host running pigpiod")
    port: int = option(8888, "pigpio: pigpiod's port", minval=1, maxval=65535)
    pins: list[int] = option([16, 20, 21, 26], "pigpio: each joint's servo GPIO (BCM), in joint "
                             "order; not a pin of the wheel driver", length=JOINT_COUNT,
                             minval=0, maxval=53)
    joints: list[str] = option(["arm_joint1", "arm_joint2", "arm_joint3", "gripper"],
                               "names of joint1, joint2, joint3 (pitch about y) and the gripper",
                               length=JOINT_COUNT)
    lower: list[float] = option([-HALF_PI, -HALF_PI, -HALF_PI, 0.0], "each joint's lowest "
                                "position (rad; the gripper's opening in m), at its min pulse",
                                length=JOINT_COUNT)
    upper: list[float] = option([HALF_PI, HALF_PI, HALF_PI, 0.035], "each joint's highest "
                                "position (rad; the gripper's opening in m), at its max pulse",
                                length=JOINT_COUNT)
    min_pulse_us: int = option(**MIN_PULSE_US)
    max_pulse_us: int = option(**MAX_PULSE_US)
    joint_min_pulse_us: list[int] = option(**JOINT_MIN_PULSE_US)
    joint_max_pulse_us: list[int] = option(**JOINT_MAX_PULSE_US)
    offsets_us: list[int] = option(**OFFSETS_US)
    reversed: list[bool] = option(**REVERSED)
    timeout_s: float = option(1.0, "pigpio: connecting to and each reply from pigpiod; pca9685: "
                              "each transfer on the simulator's emulated bus, s", above=0.0,
                              maxval=30.0)
    bus: str = option("/dev/i2c-1", "pca9685: the I2C bus, /dev/i2c-N (or N); the simulator "
                      "writes emulated:HOST:PORT", check=check_bus)
    address: int = option(DEFAULT_ADDRESS, "pca9685: the board's I2C address (64 = 0x40, "
                          "A0..A5 open)", minval=0x03, maxval=0x77)
    channels: list[int] = option([0, 1, 2, 3], "pca9685: each joint's channel (0..15), in joint "
                                 "order", length=JOINT_COUNT, minval=0, maxval=15)
    frequency_hz: float = option(SERVO_HZ, "pca9685: PWM frequency, Hz (hobby servos: 50)",
                                 minval=24.0, maxval=1526.0)
    max_speed: list[float] = option([1.0, 1.0, 1.0, 0.05], "each joint's speed limit (rad/s; "
                                    "the gripper's in m/s)", length=JOINT_COUNT, above=0.0,
                                    maxval=20.0)
    update_rate: float = option(50.0, "servo updates per second while moving", minval=5.0,
                                maxval=200.0)
    publish_rate: float = option(20.0, "/joint_states messages per second", above=0.0,
                                 maxval=100.0)
    on_stop: str = option("relax", "at shutdown and safe-stop: relax (pulses off, the servos go "
                          "limp) or home (park at the home pose and hold it)",
                          choices=("relax", "home"))
    poses: list[list[Any]] = option([], "named poses beside (or replacing) the built-in ones: "
                                    "[name, joint1, joint2, joint3, gripper_m] each",
                                    check=pose_entry_problem)

    @property
    def device(self) -> str:
        return BACKENDS[self.backend]

    def named_poses(self) -> dict[str, dict[str, float]]:
        """The built-in poses with the configured ones over them (by name), as joint targets."""
        table: dict[str, tuple[float, ...]] = dict(SEED_POSES)
        table.update({str(p[0]): tuple(float(v) for v in p[1:]) for p in self.poses})
        return {name: dict(zip(self.joints, values, strict=True))
                for name, values in table.items()}

    def pose_problems(self) -> list[str]:
        """Named poses outside the joints' limits."""
        problems = []
        for name, targets in self.named_poses().items():
            for joint, low, high in zip(self.joints, self.lower, self.upper, strict=True):
                if not low <= targets[joint] <= high:
                    problems.append(f"poses: {name}: {joint} = {targets[joint]} is "
                                    f"outside {low}..{high}")
        return problems
