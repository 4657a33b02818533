# `arbiterd map build` over a recording of `arbiterd run --sim` reproduces the live map; a
# recording it cannot use is named.
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from daemon.components.mapping.mapfile import MapData, load_map
from daemon.components.recorder.writer import recordings
from sim.mapping_truth import map_precision_recall
from tests.support.in_process_daemon import in_process_daemon
from tests.support.wait import eventually

OCCUPIED = 65


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "daemon.cli", *args], capture_output=True,
                          text=True, timeout=300, check=False)


def occupied_in(grid: MapData, frame: MapData) -> np.ndarray:
    """``grid``'s occupied cells on ``frame``'s cells (same resolution, other origin)."""
    out = np.zeros(frame.occupancy.shape, dtype=bool)
    rows, cols = np.nonzero(grid.occupancy >= OCCUPIED)
    shift_c = round((grid.origin_x - frame.origin_x) / grid.resolution)
    shift_r = round((grid.origin_y - frame.origin_y) / grid.resolution)
    rows, cols = rows + shift_r, cols + shift_c
    inside = (rows >= 0) & (rows < out.shape[0]) & (cols >= 0) & (cols < out.shape[1])
    out[rows[inside], cols[inside]] = True
    return out


async def test_a_map_built_from_the_recording_matches_the_live_one(tmp_path: Path) -> None:
    maps, rec = tmp_path / "maps", tmp_path / "rec"
    toml = (f'[mapping]\nenabled = true\npublish_period_s = 0.5\ndirectory = "{maps}"\n'
            f'[recorder]\nenabled = true\ndirectory = "{rec}"\n'
            '[autonomy]\nmode = "wander"\nseed = 3\n')
    async with in_process_daemon(tmp_path, toml) as robot:
        mapping = robot.component("mapping")
        await eventually(lambda: mapping.counters.scans >= 80, "eight seconds of mapping",
                         within_s=60)
        await robot.control.engage_estop("test: hold still for the save")
        stopped_at = mapping.counters.scans
        await eventually(lambda: mapping.counters.scans >= stopped_at + 5,
                         "the mapper to catch up")
        saved = await mapping.save("live")
    assert saved["name"] == "live"
    (recording,) = recordings(rec)
    built = run_cli("map", "build", str(recording), "--name", "offline", "--dir", str(maps),
                    "--csv", str(tmp_path / "path.csv"))
    assert built.returncode == 0, built.stderr
    assert "map offline:" in built.stdout and (tmp_path / "path.csv").is_file()
    live, offline = load_map(maps / "live.yaml"), load_map(maps / "offline.yaml")
    # the same walls within two cells (10 cm): the live mapper may have started a few
    # revolutions later (its worker's start-up) and placed revolutions at odometry ticks of
    # 50 Hz where the recording has /odom at 20 Hz, so its key scans and loop closures differ
    precision, recall = map_precision_recall(occupied_in(offline, live),
                                             occupied_in(live, live), 2)
    assert precision >= 0.85 and recall >= 0.85, (precision, recall)
    refined = run_cli("map", "build", str(recording), "--name", "refined", "--dir", str(maps),
                      "--refine", "--csv", str(tmp_path / "refined.csv"))
    assert refined.returncode == 0, refined.stderr
    assert "map refined:" in refined.stdout and "refined: " in refined.stdout
    rows = (tmp_path / "refined.csv").read_text().splitlines()
    assert len(rows) == len((tmp_path / "path.csv").read_text().splitlines())
    precision, recall = map_precision_recall(occupied_in(load_map(maps / "refined.yaml"), live),
                                             occupied_in(live, live), 2)
    assert precision >= 0.85 and recall >= 0.85, (precision, recall)


def test_a_recording_without_scans_is_named(tmp_path: Path) -> None:
    empty = tmp_path / "nothing.mcap"
    empty.write_bytes(b"\x89MCAP0\r\n")
    done = run_cli("map", "build", str(empty), "--dir", str(tmp_path))
    assert done.returncode == 1
    assert f"{empty}: " in done.stderr and "MCAP" in done.stderr
    missing = run_cli("map", "build", str(tmp_path / "gone.mcap"), "--dir", str(tmp_path))
    assert missing.returncode == 1 and "no such recording" in missing.stderr
