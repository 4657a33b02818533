# The recorder keeps the camera's frames at [camera] record_rate, readable as ROS 2 messages.
from __future__ import annotations

from pathlib import Path
from typing import Any

import simplejpeg
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from daemon.components.recorder.writer import recordings
from tests.support.in_process_daemon import in_process_daemon
from tests.support.wait import eventually


def read_camera(path: Path) -> list[tuple[str, Any]]:
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [(channel.topic, msg) for _, channel, _, msg in reader.iter_decoded_messages(
            topics=["/camera/image_raw/compressed", "/camera/camera_info"])]


async def test_the_recording_holds_jpeg_frames_at_the_record_rate(tmp_path: Path) -> None:
    directory = tmp_path / "rec"
    extra = (f'[record]\nenabled = true\ndirectory = "{directory}"\n'
             '[camera]\nenabled = true\nwidth = 96\nheight = 72\nfps = 20.0\n'
             'record_rate = 2.0\n')
    async with in_process_daemon(tmp_path, extra) as robot:
        camera = robot.ctx.components["camera"]
        # the recorder is a subscriber: the camera runs while it records
        await eventually(lambda: camera.frames >= 30, "30 frames", within_s=20.0)
        frames = camera.frames
    images = read_camera(recordings(directory)[0])
    jpegs = [m for topic, m in images if topic == "/camera/image_raw/compressed"]
    infos = [m for topic, m in images if topic == "/camera/camera_info"]
    assert jpegs and infos
    # 20 frames a second, 2 kept: about a tenth (one more for the first and the last)
    assert len(jpegs) <= frames / 10 + 2
    assert jpegs[0].format == "jpeg"
    assert simplejpeg.decode_jpeg(bytes(jpegs[0].data)).shape == (72, 96, 3)
    assert infos[0].width == 96 and len(infos[0].k) == 9
