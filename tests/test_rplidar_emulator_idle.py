# The RPLIDAR emulator sleeps while nothing is due: no busy polling at rest.
from __future__ import annotations

from pathlib import Path

from sim.rplidar_emulator import A1, BATCH_S, IDLE_S, RplidarEmulator


def test_the_emulator_waits_for_its_next_batch_or_a_request(tmp_path: Path) -> None:
    emulator = RplidarEmulator(tmp_path / "lidar", A1)
    assert emulator._wait_s(0.0) == IDLE_S  # not scanning: only a request wakes it
    emulator._begin(A1.modes[1])
    assert emulator._wait_s(0.0) == BATCH_S  # scanning: one batch of capsules per wake-up
    assert BATCH_S >= 0.02 and IDLE_S >= 0.1
    emulator._stream = None
    emulator._out.clear()
    emulator._banner_at = 5.0  # after a RESET: the banner comes on time
    assert emulator._wait_s(4.99) <= 0.0101
