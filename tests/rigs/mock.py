# Rig for the mock driver: no emulator; the driver's own record is what the "hardware" saw.
from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any


class MockRig:
    driver_name = "mock"

    def __init__(self) -> None:
        self.options: dict[str, Any] = {}
        self.motors = None
        self.driver: Any = None

    def observed_targets(self) -> tuple[float, float]:
        cmd = self.driver.commands[-1]
        return cmd.left_rad_s, cmd.right_rad_s


@asynccontextmanager
async def rig(tmp_path: Path) -> AsyncIterator[MockRig]:
    yield MockRig()
