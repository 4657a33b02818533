# [arm]: the servo backend, each joint's output, limits, calibration and speed, and the named poses.
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from base.config import SectionSettings
from base.options import Option, Options
from drivers.i2c_link import check_bus
from drivers.mock_servo import MOCK_SERVO_OPTIONS
from drivers.pca9685_protocol import DEFAULT_ADDRESS
from drivers.pca9685_servo import PCA9685_OPTIONS
from drivers.pigpio_servo import SERVO_OPTIONS
from drivers.servo_array import CalibrationSettings
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


def _per_joint(default: list[Any], doc: str, item: type, **bounds: Any) -> Option:
    return Option(list, default, doc, item=item, length=JOINT_COUNT, **bounds)


ARM_OPTIONS: Options = {
    "enabled": Option(bool, False, "drive the arm and gripper servos"),
    "backend": Option(str, "mock", "servo output: pigpio (pigpiod's servo pulses on GPIO "
                      "pins), pca9685 (a PCA9685 board over I2C) or mock (records)",
                      choices=tuple(BACKENDS)),
    **SERVO_OPTIONS,
    **PCA9685_OPTIONS,
    **{k: v for k, v in MOCK_SERVO_OPTIONS.items() if k not in ("history",)},
    "host": Option(str, "localhost", "pigpio: the host running pigpiod"),
    "port": Option(int, 8888, "pigpio: pigpiod's port", minval=1, maxval=65535),
    "timeout_s": Option(float, 1.0, "pigpio: connecting to and each reply from pigpiod; "
                        "pca9685: each transfer on the simulator's emulated bus, s", above=0.0,
                        maxval=30.0),
    "bus": Option(str, "/dev/i2c-1", "pca9685: the I2C bus, /dev/i2c-N (or N); the simulator "
                  "writes emulated:HOST:PORT", check=check_bus),
    "address": Option(int, DEFAULT_ADDRESS, "pca9685: the board's I2C address (64 = 0x40, "
                      "A0..A5 open)", minval=0x03, maxval=0x77),
    "frequency_hz": Option(float, SERVO_HZ, "pca9685: PWM frequency, Hz (hobby servos: 50)",
                           minval=24.0, maxval=1526.0),
    "joints": _per_joint(["arm_joint1", "arm_joint2", "arm_joint3", "gripper"],
                         "names of joint1, joint2, joint3 (pitch about y) and the gripper",
                         str),
    "pins": _per_joint([16, 20, 21, 26], "pigpio: each joint's servo GPIO (BCM), in joint "
                       "order; not a pin of the wheel driver", int, minval=0, maxval=53),
    "channels": _per_joint([0, 1, 2, 3], "pca9685: each joint's channel (0..15), in joint "
                           "order", int, minval=0, maxval=15),
    "lower": _per_joint([-HALF_PI, -HALF_PI, -HALF_PI, 0.0], "each joint's lowest position "
                        "(rad; the gripper's opening in m), at its min pulse", float),
    "upper": _per_joint([HALF_PI, HALF_PI, HALF_PI, 0.035], "each joint's highest position "
                        "(rad; the gripper's opening in m), at its max pulse", float),
    "max_speed": _per_joint([1.0, 1.0, 1.0, 0.05], "each joint's speed limit (rad/s; the "
                            "gripper's in m/s)", float, above=0.0, maxval=20.0),
    "update_rate": Option(float, 50.0, "servo updates per second while moving", minval=5.0,
                          maxval=200.0),
    "publish_rate": Option(float, 20.0, "/joint_states messages per second", above=0.0,
                           maxval=100.0),
    "on_stop": Option(str, "relax", "at shutdown and safe-stop: relax (pulses off, the servos "
                      "go limp) or home (park at the home pose and hold it)",
                      choices=("relax", "home")),
    "poses": Option(list, [], "named poses beside (or replacing) the built-in ones: "
                    "[name, joint1, joint2, joint3, gripper_m] each", item=list,
                    check=pose_entry_problem),
}


@dataclass(frozen=True)
class ArmSettings(CalibrationSettings, SectionSettings, section="arm", options=ARM_OPTIONS):
    """The [arm] section, read once (the servo calibration fields come from the drivers'
    CalibrationSettings). Device keys are read by the device itself."""

    enabled: bool
    backend: str
    host: str
    port: int
    pins: list[int]
    timeout_s: float
    bus: str
    address: int
    channels: list[int]
    frequency_hz: float
    max_speed: list[float]
    update_rate: float
    publish_rate: float
    on_stop: str
    poses: list[list[Any]]

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
