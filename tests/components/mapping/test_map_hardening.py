# The maps directory is not trusted: links, FIFOs, huge maps, stalled downloads, full disks.
from __future__ import annotations

import asyncio
import os
import time
from collections.abc import AsyncIterator
from pathlib import Path

import aiohttp
import numpy as np
import pytest

from daemon.components.mapping.mapfile import MapData, MapFileError, load_map, save_map
from daemon.files import FileRefused
from tests.support.daemon_subprocess import StartDaemonSubprocess
from tests.support.http_raw import exchange, request, stalled_download
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rosbridge import OWNER, WITH_TOKEN
from tests.support.wait import wait_for

GOOD_YAML = "image: {image}\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\n"


def write_map(directory: Path, name: str, width: int, height: int) -> None:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / f"{name}.pgm").write_bytes(f"P5\n{width} {height}\n255\n".encode()
                                            + bytes([254]) * (width * height))
    (directory / f"{name}.yaml").write_text(GOOD_YAML.format(image=f"{name}.pgm"))


@pytest.fixture
async def robot(tmp_path: Path) -> AsyncIterator[InProcessDaemon]:
    maps = tmp_path / "maps"
    write_map(maps, "room", 4, 2)
    toml = WITH_TOKEN + f'[mapping]\nenabled = true\ndirectory = "{maps}"\nmax_saved_mb = 1\n'
    async with in_process_daemon(tmp_path, toml) as robot:
        yield robot


async def get(robot: InProcessDaemon, path: str, headers: dict[str, str] | None = None,
              ) -> tuple[int, bytes]:
    async with aiohttp.ClientSession() as session, asyncio.timeout(10), session.get(
            robot.http_url + path, headers=headers) as response:
        return response.status, await response.read()


async def test_links_and_fifos_in_the_maps_directory_are_refused_without_hanging(
        robot: InProcessDaemon, tmp_path: Path) -> None:
    """Before: a link was followed without a token (a file outside served), and a FIFO named
    like a map image hung GET /api/maps, map saves and the daemon's shutdown."""
    maps = tmp_path / "maps"
    secret = tmp_path / "secret.pgm"
    secret.write_bytes(b"P5\n1 1\n255\n\x00")
    (maps / "stolen.pgm").symlink_to(secret)
    os.mkfifo(maps / "trap.pgm")
    (maps / "trap.yaml").write_text(GOOD_YAML.format(image="trap.pgm"))
    os.mkfifo(maps / ".room.pgm.partial")  # a FIFO where the next save writes first
    for name in ("stolen.pgm", "trap.pgm"):
        assert (await get(robot, f"/api/maps/{name}", OWNER))[0] == 404
    status, body = await get(robot, "/api/maps")  # tokenless reads are allowed: no paths
    assert status == 200 and b"trap" in body and str(tmp_path).encode() not in body
    status, body = await get(robot, "/api/maps", OWNER)
    assert status == 200 and str(maps).encode() in body  # the owner sees where
    assert (await get(robot, "/api/maps/room.pgm"))[0] == 200


async def test_saved_maps_are_capped(robot: InProcessDaemon, tmp_path: Path) -> None:
    """Before: 50 saves filled 13.7 MB with no limit; now [mapping] max_saved_mb (1 here)."""
    mapping = robot.component("mapping")
    mapping.latest_map = MapData(np.zeros((700, 700), np.int8), 0.05, 0.0, 0.0)
    mapping._fetch_map = _nothing
    async with aiohttp.ClientSession() as session:
        statuses = []
        for i in range(4):
            async with session.post(robot.http_url + "/api/map/save", json={"name": f"m{i}"},
                                    headers=OWNER) as response:
                statuses.append(response.status)
    assert statuses == [200, 200, 507, 507]
    assert sum(p.stat().st_size for p in (tmp_path / "maps").iterdir()) < 1_000_000


async def _nothing() -> None:
    return None


def test_a_25_million_cell_map_is_refused_from_its_header(tmp_path: Path) -> None:
    """Before: loading it stalled the loop 6.9 s and took the daemon to 662 MB. The image
    here is only its header: had anything read further, it would say "truncated"."""
    (tmp_path / "huge.pgm").write_bytes(b"P5\n5000 5000\n255\n")
    (tmp_path / "huge.yaml").write_text(GOOD_YAML.format(image="huge.pgm"))
    started = time.perf_counter()
    with pytest.raises(MapFileError, match="25000000 cells: at most 4000000"):
        load_map(tmp_path / "huge.yaml", 4_000_000)
    print(f"25 M-cell map refused in {1000 * (time.perf_counter() - started):.1f} ms")


def test_a_map_image_outside_the_directory_is_refused(tmp_path: Path) -> None:
    (tmp_path / "m.yaml").write_text(GOOD_YAML.format(image="/etc/passwd"))
    with pytest.raises(MapFileError, match="image: expected a file name beside the YAML"):
        load_map(tmp_path / "m.yaml")


def test_a_save_never_writes_through_a_link(tmp_path: Path) -> None:
    target = tmp_path / "elsewhere"
    target.write_bytes(b"keep")
    maps = tmp_path / "maps"
    maps.mkdir()
    (maps / ".m.pgm.partial").symlink_to(target)
    save_map(maps, "m", MapData(np.zeros((2, 2), np.int8), 0.05, 0.0, 0.0))
    assert target.read_bytes() == b"keep" and not (maps / "m.pgm").is_symlink()
    with pytest.raises(FileRefused):
        save_map(maps, "n", MapData(np.zeros((100, 100), np.int8), 0.05, 0.0, 0.0), 5000)


def test_stalled_map_downloads_leave_the_api_answering(
        daemon_subprocess: StartDaemonSubprocess, tmp_path: Path) -> None:
    """Before: 264 never-read downloads of a 4 MB map held every HTTP slot for 30 s and more
    (GET /api/maps/<file> had no send deadline). Here 20 with the cap at 16: the slots come
    free within send_timeout_s (2 s) and /api/status answers again."""
    maps = tmp_path / "maps"
    write_map(maps, "big", 2000, 2000)
    proc = daemon_subprocess(f'[lidar]\nenabled = true\n[mapping]\nenabled = true\n'
                             f'directory = "{maps}"\n',
                             env={"ARBITERD_HTTP_MAX_CONNECTIONS": "16",
                                  "ARBITERD_HTTP_SEND_TIMEOUT_S": "2"})
    downloads = []
    try:
        for _ in range(20):
            try:
                downloads.append(stalled_download(proc.http_port, "", "/api/maps/big.pgm"))
            except (OSError, AssertionError):
                continue
        assert len(downloads) >= 16
        started = time.monotonic()
        wait_for(lambda: status_answers(proc.http_port), "GET /api/status to answer again")
        print(f"{len(downloads)} stalled map downloads: /api/status answers again after "
              f"{time.monotonic() - started:.1f} s (send_timeout_s 2)")
    finally:
        for sock in downloads:
            sock.close()
    assert "made no progress for 2 s" in proc.log()
    assert "Traceback" not in proc.log()


def status_answers(port: int) -> bool:
    try:
        return exchange(port, request("GET", "/api/status", port), 1.0).status == 200
    except (OSError, AssertionError):
        return False
