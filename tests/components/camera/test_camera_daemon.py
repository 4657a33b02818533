# The camera in `run --sim`: snapshot, MJPEG stream, rosbridge topics, refusals, slow viewers.
from __future__ import annotations

import asyncio
import base64
import math
import socket
from pathlib import Path
from typing import Any

import aiohttp
import numpy as np
import simplejpeg

from daemon.components.camera.component import CAMERA_IMAGE
from sim.objects import OBJECT_COLORS
from tests.support.in_process_daemon import in_process_daemon
from tests.support.rosbridge import connect
from tests.support.wait import eventually

CAMERA = '[camera]\nenabled = true\nwidth = 160\nheight = 120\nfps = 10.0\n'


def camera_of(robot: Any) -> Any:
    return robot.ctx.components["camera"]


async def test_camera_is_off_by_default(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path) as robot, aiohttp.ClientSession() as http, \
            http.get(f"{robot.http_url}/api/camera/snapshot") as answer:
        assert answer.status == 404


async def test_snapshot_shows_the_world_and_a_red_object_where_the_truth_says(
        tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, CAMERA) as robot, aiohttp.ClientSession() as http:
        camera = camera_of(robot)
        assert camera.driver == "sim" and camera.frames == 0  # nobody watched yet
        world = robot.ctx.sim.world
        truth = world.ground_truth()
        # an object 1 m straight ahead of the camera
        ahead = 1.0 + camera.model.x
        world.place_object(truth.x + ahead * math.cos(truth.theta),
                           truth.y + ahead * math.sin(truth.theta), "red")
        async with http.get(f"{robot.http_url}/api/camera/snapshot") as answer:
            assert answer.status == 200
            assert answer.content_type == "image/jpeg"
            jpeg = await answer.read()
        image = simplejpeg.decode_jpeg(jpeg)
        assert image.shape == (120, 160, 3)
        assert image.std() > 10  # not blank: sky, floor, walls
        red = np.array(OBJECT_COLORS["red"], float)
        near_red = np.linalg.norm(image.astype(float) - red * 0.85, axis=2) < 60
        _, cols = np.nonzero(near_red)
        assert len(cols) > 4, "the red object is not in the image"
        assert abs(cols.mean() - 80) < 4  # straight ahead: the middle column


async def test_stream_sends_jpeg_parts_and_stops_when_the_viewer_leaves(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, CAMERA) as robot, aiohttp.ClientSession() as http:
        camera = camera_of(robot)
        async with http.get(f"{robot.http_url}/api/camera/stream") as answer:
            assert answer.status == 200
            assert answer.headers["Content-Type"].startswith("multipart/x-mixed-replace")
            data = b""
            while data.count(b"\xff\xd9") < 3:
                data += await answer.content.readany()
            assert data.startswith(b"--arbiterdframe\r\nContent-Type: image/jpeg\r\n")
        await eventually(lambda: camera.viewers == 0, "the viewer to be gone")
        frames = camera.frames
        await asyncio.sleep(0.5)  # nobody watches: no frame is made
        assert camera.frames <= frames + 1
        assert camera.demand() == 0


async def test_rosbridge_gets_compressed_images_and_camera_info(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, CAMERA) as robot:
        async with connect(robot.ws_url) as client:
            await client.send(op="subscribe", topic="/camera/image_raw/compressed",
                              type="sensor_msgs/msg/CompressedImage")
            await client.send(op="subscribe", topic="/camera/camera_info")
            image = await client.expect(lambda m: m.get("topic") ==
                                        "/camera/image_raw/compressed")
            info = await client.expect(lambda m: m.get("topic") == "/camera/camera_info")
        msg = image["msg"]
        assert msg["format"] == "jpeg" and msg["header"]["frame_id"] == "camera"
        assert simplejpeg.decode_jpeg(base64.b64decode(msg["data"])).shape == (120, 160, 3)
        assert info["msg"]["width"] == 160 and info["msg"]["height"] == 120
        k = info["msg"]["k"]
        assert k[2] == 80 and k[5] == 60 and k[0] > 0
        await eventually(lambda: robot.ctx.bus.subscribers(CAMERA_IMAGE) == 0,
                         "rosbridge to let go of the camera")


async def test_camera_settings_need_the_token_and_valid_values(tmp_path: Path) -> None:
    extra = CAMERA + '[security]\ntoken = "secret-token-1234"\n'
    async with in_process_daemon(tmp_path, extra) as robot, aiohttp.ClientSession() as http:
        url = f"{robot.http_url}/api/camera"
        async with http.post(url, json={"fps": 5}) as answer:
            assert answer.status == 401
        auth = {"Authorization": "Bearer secret-token-1234"}
        for bad in (0, -1, 1e308, "5", True, None, 11):
            async with http.post(url, json={"fps": bad}, headers=auth) as answer:
                assert answer.status == 422, bad
                assert "fps" in (await answer.json())["error"]
        async with http.post(url, data=b'{"fps": NaN}', headers={
                **auth, "Content-Type": "application/json"}) as answer:
            assert answer.status == 400
        async with http.post(url, json={"zoom": 2}, headers=auth) as answer:
            assert answer.status == 422 and "zoom" in (await answer.json())["error"]
        async with http.post(url, json={"fps": 5}, headers=auth) as answer:
            assert answer.status == 200 and (await answer.json())["fps"] == 5
        async with http.get(url) as answer:  # reading needs no token
            assert answer.status == 200


async def test_a_stalled_viewer_is_cut_off_and_the_others_go_on(tmp_path: Path) -> None:
    extra = CAMERA.replace("fps = 10.0", "fps = 30.0") + "send_timeout_s = 0.5\nsim_noise = 30.0\n"
    async with in_process_daemon(tmp_path, extra) as robot, aiohttp.ClientSession() as http:
        camera = camera_of(robot)
        port = int(robot.http_url.rsplit(":", 1)[1])
        stalled = socket.create_connection(("127.0.0.1", port))
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stalled.sendall(b"GET /api/camera/stream HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        try:
            async with http.get(f"{robot.http_url}/api/camera/stream") as answer:
                await eventually(lambda: camera.cut_off == 1, "the stalled viewer to be cut off",
                                 within_s=20.0)
                data = b""
                while data.count(b"\xff\xd9") < 2:
                    data += await answer.content.readany()  # this one still gets frames
        finally:
            stalled.close()
        await eventually(lambda: camera.viewers == 0, "both viewers to be gone")


async def test_more_viewers_than_allowed_are_refused(tmp_path: Path) -> None:
    extra = CAMERA + "max_viewers = 2\n"
    async with in_process_daemon(tmp_path, extra) as robot, aiohttp.ClientSession() as http:
        url = f"{robot.http_url}/api/camera/stream"
        first, second = await http.get(url), await http.get(url)
        try:
            async with http.get(url) as third:
                assert third.status == 503
                assert "max_viewers" in (await third.json())["error"]
        finally:
            first.close()
            second.close()
