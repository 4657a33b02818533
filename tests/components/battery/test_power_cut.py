# Power cuts: SIGKILL at random moments while recording and saving maps; every file reads back.
from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

from daemon.components.mapping.mapfile import load_map
from daemon.components.recorder.files import inspect

REPO = Path(__file__).resolve().parents[3]
CUTS = 20

#: a recorder writing /battery_state at 50 Hz (1 s chunks, the daemon's default), and a map
#: saved over and over; it prints "go" once the first chunk is on the disk
WRITER = r"""
import sys, time
from pathlib import Path
import numpy as np
from daemon.components.battery.charge import Reading
from daemon.components.battery.component import battery_state_msg
from daemon.components.mapping.mapfile import save_map
from daemon.components.recorder.channels import Channel
from daemon.components.recorder.writer import FlightRecorder, WriterOptions
from daemon.components.mapping.mapfile import MapData

out = Path(sys.argv[1])
channel = Channel("/battery_state", "sensor_msgs/msg/BatteryState", battery_state_msg)
recorder = FlightRecorder(WriterOptions(out / "rec", 1 << 30, 3600.0, 1 << 31, "none", 1.0,
                                        10000), [channel])
recorder.start()
recorder.wanted = True
grid = np.zeros((64, 64), dtype=np.int8)
said = False
while True:
    now = time.time()
    recorder.enqueue((channel,), Reading(now, 12.0, -0.5, 0.8, "discharging", "ok"))
    grid[int(now * 50) % 64, :] = 100
    save_map(out / "maps", "live", MapData(grid, 0.05, 0.0, 0.0))
    if not said and recorder.file_bytes > 200:  # the first chunk closed
        print("go", flush=True)
        said = True
    time.sleep(0.02)
"""


def test_every_recording_and_map_survives_a_power_cut(tmp_path: Path) -> None:
    rng = random.Random(36)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    for cut in range(CUTS):
        out = tmp_path / f"cut{cut}"
        process = subprocess.Popen([sys.executable, "-c", WRITER, str(out)], env=env,
                                   stdout=subprocess.PIPE, text=True)
        try:
            assert process.stdout is not None
            assert process.stdout.readline().strip() == "go", "the writer did not start"
            time.sleep(rng.uniform(0.0, 1.5))  # a random moment in the recording
            killed_at = time.time()
            process.send_signal(signal.SIGKILL)
            assert process.wait(10) == -signal.SIGKILL
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
        recordings = sorted((out / "rec").glob("*.mcap"))
        assert recordings, f"cut {cut}: no recording"
        for path in recordings:
            info = inspect(path)
            assert info.end_ns is not None and info.topics["/battery_state"].count > 0
            # chunks close every second: at most the chunk in progress is lost (+ slack)
            assert info.end_ns / 1e9 > killed_at - 1.0 - 2.5, f"cut {cut}: {path.name}"
        grid = load_map(out / "maps" / "live.yaml")
        assert grid.occupancy.shape == (64, 64), f"cut {cut}: the saved map"
