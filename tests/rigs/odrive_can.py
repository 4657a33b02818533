# Rig for the odrive_can driver: an emulated ODrive answering CANSimple on a python-can virtual bus.
from __future__ import annotations

import uuid
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from sim.motor_model import MotorPair
from sim.odrive_emulator import ODriveEmulator, start_odrive_emulator

LEFT_NODE, RIGHT_NODE = 3, 4


class ODriveRig:
    """The running emulator plus the ``[driver.odrive_can]`` options that reach it."""

    driver_name = "odrive_can"
    wheel_sign = 1

    def __init__(self, emulator: ODriveEmulator) -> None:
        self.emulator = emulator
        self.motors = emulator.motors
        self.options: dict[str, Any] = {
            "interface": emulator.interface,
            "channel": emulator.channel,
            "left_node_id": LEFT_NODE,
            "right_node_id": RIGHT_NODE,
            "left_inverted": False,
            "right_inverted": True,
        }

    def observed_targets(self) -> tuple[float, float]:
        """Wheel set-points (rad/s, forward positive) from the velocity inputs the axes obey."""
        return self.emulator.wheel_targets()


@asynccontextmanager
async def rig(tmp_path: Path, motors: MotorPair | None = None) -> AsyncIterator[ODriveRig]:
    # a virtual bus channel of its own, so concurrent rigs never hear each other
    channel = f"odrive-{tmp_path.name}-{uuid.uuid4().hex[:8]}"
    emulator = start_odrive_emulator("virtual", channel, (LEFT_NODE, RIGHT_NODE), motors,
                                     directions=(1, -1))
    try:
        yield ODriveRig(emulator)
    finally:
        emulator.stop()
