# The mapping component in `arbiterd run --sim`: /map, /pose, map -> odom and /tf_static over
# rosbridge, maps saved, listed, downloaded and loaded again; bad input refused, nothing lost.
from __future__ import annotations

import base64
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import aiohttp
import numpy as np
import pytest
import yaml

from tests.support.daemon_subprocess import StartDaemonSubprocess
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rosbridge import connect
from tests.support.wait import eventually, wait_for

MAPPING = '[mapping]\nenabled = true\npublish_period_s = 0.5\ndirectory = "{maps}"\n'


def mapping_toml(tmp_path: Path, extra: str = "") -> str:
    return MAPPING.format(maps=tmp_path / "maps") + extra


async def get(robot: InProcessDaemon, path: str) -> tuple[int, Any]:
    async with aiohttp.ClientSession() as http, http.get(robot.http_url + path) as response:
        body = await response.json() if response.content_type == "application/json" else \
            await response.read()
        return response.status, body


async def post(robot: InProcessDaemon, path: str, body: Any) -> tuple[int, Any]:
    async with aiohttp.ClientSession() as http, \
            http.post(robot.http_url + path, json=body) as response:
        return response.status, await response.json()


async def a_map(robot: InProcessDaemon) -> dict[str, Any]:
    await eventually(lambda: robot.component("mapping").latest_map is not None,
                     "the first map", within_s=30)
    status, grid = await get(robot, "/api/map")
    assert status == 200
    return grid


async def test_the_map_pose_and_transforms_reach_a_rosbridge_client(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, mapping_toml(tmp_path)) as robot, \
            connect(robot.ws_url) as client:
        for topic in ("/map", "/pose", "/tf", "/tf_static"):
            await client.send(op="subscribe", topic=topic)
        grid = await client.expect(lambda m: m.get("topic") == "/map", what="/map",
                                   within=30)
        info = grid["msg"]["info"]
        assert grid["msg"]["header"]["frame_id"] == "map"
        assert abs(info["resolution"] - 0.05) < 1e-6
        assert len(grid["msg"]["data"]) == info["width"] * info["height"]
        values = set(grid["msg"]["data"])
        assert values <= set(range(-1, 101)) and {-1} < values  # unknown and seen cells
        pose = await client.expect(lambda m: m.get("topic") == "/pose", what="/pose")
        assert pose["msg"]["header"]["frame_id"] == "map"
        await client.expect(lambda m: m.get("topic") == "/tf" and any(
            t["header"]["frame_id"] == "map" and t["child_frame_id"] == "odom"
            for t in m["msg"]["transforms"]), what="map -> odom on /tf")
        static = await client.expect(lambda m: m.get("topic") == "/tf_static",
                                     what="/tf_static")
        (mount,) = static["msg"]["transforms"]
        assert (mount["header"]["frame_id"], mount["child_frame_id"]) == ("base_link", "laser")
        health = robot.component("mapping").health().to_json()
        assert health["status"] == "ok" and health["revolutions"] > 0


async def test_a_saved_map_is_listed_downloaded_and_localised_in(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, mapping_toml(tmp_path)) as robot:
        live = await a_map(robot)
        status, saved = await post(robot, "/api/map/save", {"name": "lab"})
        assert status == 200, saved
        status, listing = await get(robot, "/api/maps")
        assert [m["name"] for m in listing["maps"]] == ["lab"]
        status, text = await get(robot, "/api/maps/lab.yaml")
        assert status == 200 and yaml.safe_load(text)["image"] == "lab.pgm"
        status, pgm = await get(robot, "/api/maps/lab.pgm")
        assert status == 200 and pgm.startswith(b"P5")
        cells = np.frombuffer(base64.b64decode(live["data"]), np.int8)
        assert cells.size == live["width"] * live["height"]

        status, body = await post(robot, "/api/map/load", {"name": "lab"})
        assert status == 200 and body["mode"] == "localize" and body["map"] == "lab", body
        status, body = await post(robot, "/api/pose", {"x": 0.0, "y": 0.0, "theta": 0.0})
        assert status == 200, body
        mapping = robot.component("mapping")
        revolutions = mapping.counters.scans
        await eventually(lambda: mapping.counters.scans > revolutions + 5,
                         "revolutions tracked in the saved map")
        assert not mapping.health().values["lost"]


async def test_a_map_loaded_without_a_pose_finds_the_pose_by_itself(tmp_path: Path) -> None:
    wander = '[autonomy]\nmode = "wander"\nseed = 3\n'
    async with in_process_daemon(tmp_path, mapping_toml(tmp_path, wander)) as robot:
        mapping = robot.component("mapping")
        await eventually(lambda: mapping.counters.scans >= 100, "ten seconds of mapping",
                         within_s=60)
        await robot.control.engage_estop("test: hold still")
        stopped_at = mapping.counters.scans
        await eventually(lambda: mapping.counters.scans >= stopped_at + 5, "still scans")
        assert mapping.last is not None
        here = mapping.last.pose
        status, saved = await post(robot, "/api/map/save", {"name": "room"})
        assert status == 200, saved
        status, body = await post(robot, "/api/map/load", {"name": "room"})  # no pose given
        assert status == 200 and body["mode"] == "localize", body
        await eventually(lambda: mapping.health().values.get("localisation") == "tracking",
                         lambda: f"the pose found on the whole map: {mapping.status()}",
                         within_s=30)
        pose = mapping.health().values["pose"]
        assert abs(pose[0] - here[0]) < 0.1 and abs(pose[1] - here[1]) < 0.1, (pose, here)


async def test_bad_requests_are_refused_and_the_old_map_stays(tmp_path: Path) -> None:
    maps = tmp_path / "maps"
    async with in_process_daemon(tmp_path, mapping_toml(tmp_path)) as robot:
        await a_map(robot)
        maps.mkdir(exist_ok=True)
        (maps / "broken.yaml").write_text("image: broken.pgm\nresolution: 0.05\n"
                                          "origin: [0, 0, 0]\n")
        (maps / "broken.pgm").write_bytes(b"P5\n10 10\n255\n" + bytes(20))
        (maps / "coarse.yaml").write_text("image: coarse.pgm\nresolution: 0.1\n"
                                          "origin: [0, 0, 0]\n")
        (maps / "coarse.pgm").write_bytes(b"P5\n2 1\n255\n" + bytes(2))
        for body, problem in (({"name": "broken"}, "truncated"),
                              ({"name": "coarse"}, "0.1 m cells"),
                              ({"name": "nothing"}, "no such map file"),
                              ({"name": "../etc/passwd"}, "not a map name")):
            status, answer = await post(robot, "/api/map/load", body)
            assert status == 422 and problem in answer["error"], answer
        assert robot.component("mapping").settings.mode == "map"
        for raw, problem in (('{"x": NaN, "y": 0}', "not valid JSON"),
                             ('{"x": "1", "y": 0}', "x: expected a finite number"),
                             ('{"x": 1, "y": 0, "z": 2}', "z: unknown field")):
            async with aiohttp.ClientSession() as http, http.post(
                    robot.http_url + "/api/pose", data=raw,
                    headers={"Content-Type": "application/json"}) as r:
                assert r.status in (400, 422)
                assert problem in (await r.json())["error"]
        status, answer = await post(robot, "/api/map/save", {"name": "a/b"})
        assert status == 422 and "not a map name" in answer["error"]
        status, answer = await get(robot, "/api/maps/..%2Fsecret.yaml")
        assert status == 404


async def test_an_initial_pose_in_another_frame_is_refused(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, mapping_toml(tmp_path)) as robot, \
            connect(robot.ws_url) as client:
        await a_map(robot)
        await client.send(op="advertise", topic="/initialpose",
                          type="geometry_msgs/msg/PoseWithCovarianceStamped")
        await client.send(op="publish", topic="/initialpose", id="p", msg={
            "header": {"frame_id": "odom"},
            "pose": {"pose": {"position": {"x": 1.0, "y": 0.0, "z": 0.0},
                              "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}}}})
        status = await client.op("status", id="p")
        assert status["level"] == "error" and "frame_id is 'odom'" in status["msg"]


def children_of(pid: int) -> set[int]:
    found = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        text = (task / "children").read_text() if (task / "children").exists() else ""
        found |= {int(child) for child in text.split()}
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_the_mapper_process_ends_with_the_daemon(daemon_subprocess: StartDaemonSubprocess,
                                                  tmp_path: Path, sig: int) -> None:
    daemon = daemon_subprocess(mapping_toml(tmp_path), args=("--sim",))
    wait_for(lambda: daemon.get("/api/health")[1]["components"]["mapping"]["revolutions"] > 0,
             "the mapper's first revolution", within_s=30)
    assert daemon.proc is not None
    workers = children_of(daemon.proc.pid)
    assert workers, "the mapper runs in a process of its own"
    daemon.stop(sig)
    wait_for(lambda: not any(alive(pid) for pid in workers), "the mapper process to end")


def test_map_save_and_list_from_the_command_line(daemon_subprocess: StartDaemonSubprocess,
                                                 tmp_path: Path) -> None:
    daemon = daemon_subprocess(mapping_toml(tmp_path), args=("--sim",))
    wait_for(lambda: daemon.get("/api/health")[1]["components"]["mapping"]["maps_published"],
             "the first map", within_s=30)
    url = ("--url", daemon.base_url)
    saved = subprocess.run([sys.executable, "-m", "daemon.cli", "map", "save", "hall", *url],
                           capture_output=True, text=True, timeout=60, check=False)
    assert saved.returncode == 0, saved.stderr
    assert "saved as hall.yaml + hall.pgm" in saved.stdout
    listed = subprocess.run([sys.executable, "-m", "daemon.cli", "map", "list", "--dir",
                             str(tmp_path / "maps")], capture_output=True, text=True,
                            timeout=60, check=False)
    assert listed.returncode == 0 and listed.stdout.startswith("hall "), listed.stdout
    refused = subprocess.run([sys.executable, "-m", "daemon.cli", "map", "save", "../x", *url],
                             capture_output=True, text=True, timeout=60, check=False)
    assert refused.returncode == 2 and "not a map name" in refused.stderr
