# Bench suite "camera": sim render + JPEG encode per frame; tick lateness and CPU with one MJPEG
# viewer beside nobody watching, in turns in one run; frames made while nobody watches.
from __future__ import annotations

import asyncio
import contextlib
import math
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

from daemon.bench import BenchResult, free_port, ms_result, percentile_ms, run_quietly

SUITE = "camera"
#: the viewer: a separate process reading the MJPEG stream as a browser would
VIEWER = """
import sys, time, urllib.request
end = time.monotonic() + float(sys.argv[2])
with urllib.request.urlopen(sys.argv[1], timeout=10) as stream:
    while time.monotonic() < end:
        stream.read(65536)
"""


def render_costs(quick: bool) -> list[BenchResult]:
    """ms per frame to draw the warehouse and encode it, at 320x240 and 640x480."""
    from sim.camera import CameraModel, CameraRenderer, encode_jpeg
    from sim.world import load_world

    world = load_world("warehouse")
    pose = (world.start.x, world.start.y, world.start.theta)
    objects = [(5.0, 0.2, 0.0225, "red"), (4.0, -0.5, 0.0225, "blue")]
    repeats = 10 if quick else 50
    out = []
    for width, height in ((320, 240), (640, 480)):
        renderer = CameraRenderer(world, CameraModel(width, height))
        image = renderer.render(pose, objects)
        t0 = time.perf_counter()
        for _ in range(repeats):
            image = renderer.render(pose, objects)
        t1 = time.perf_counter()
        for _ in range(repeats):
            jpeg = encode_jpeg(image, 80)
        t2 = time.perf_counter()
        out += [ms_result(SUITE, f"sim render {width}x{height}", (t1 - t0) / repeats * 1e3),
                ms_result(SUITE, f"JPEG encode {width}x{height} (simplejpeg, q80)",
                          (t2 - t1) / repeats * 1e3, note=f"{len(jpeg)} bytes")]
    return out


@contextlib.asynccontextmanager
async def camera_daemon(workdir: Path, fps: float) -> AsyncIterator[tuple[Any, str]]:
    """``run --sim`` (mock wheels) with the camera on at 640x480: (daemon, HTTP URL)."""
    from daemon.app import Daemon
    from daemon.config import load_config

    http_port = free_port()
    path = workdir / "bench.toml"
    path.write_text(f'[http]\nhost = "127.0.0.1"\nport = {http_port}\n'
                    f'[rosbridge]\nhost = "127.0.0.1"\nport = {free_port()}\n'
                    '[sim]\ndriver = "mock"\n'
                    f'[camera]\nenabled = true\nwidth = 640\nheight = 480\nfps = {fps}\n')
    daemon = Daemon(load_config(path, sim=True))
    task = asyncio.create_task(daemon.run())
    while daemon.state == "startup":
        if task.done():
            raise RuntimeError(f"bench daemon did not start (exit {task.result()})")
        await asyncio.sleep(0.01)
    try:
        yield daemon, f"http://127.0.0.1:{http_port}"
    finally:
        daemon.request_shutdown("bench over")
        await task


def _watching(camera: Any, viewer: asyncio.subprocess.Process) -> Callable[[], bool]:
    return lambda: camera.viewers > 0 or viewer.returncode is not None


async def _until(condition: Callable[[], bool]) -> None:
    """Poll ``condition`` (the component's counters) every 10 ms until it holds."""
    while not condition():  # noqa: ASYNC110 (a counter, no event to wait on)
        await asyncio.sleep(0.01)


async def _segment(daemon: Any, seconds: float) -> tuple[list[float], float]:
    """Tick lateness samples (s) and process CPU (fraction of a core) over ``seconds``."""
    daemon.latency.tick_late_ms.clear()
    cpu0, t0 = time.process_time(), time.monotonic()
    await asyncio.sleep(seconds)
    cpu = (time.process_time() - cpu0) / (time.monotonic() - t0)
    return [ms / 1e3 for ms in daemon.latency.tick_late_ms], cpu


async def _ticks(quick: bool) -> list[BenchResult]:
    segment, turns = (1.5, 2) if quick else (5.0, 4)
    fps = 15.0
    idle: list[float] = []
    watched: list[float] = []
    cpu: dict[str, list[float]] = {"idle": [], "watched": []}
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-") as tmp:
        async with camera_daemon(Path(tmp), fps) as (daemon, url):
            camera = next(c for c in daemon.components if c.name == "camera")
            await asyncio.sleep(0.5)
            unwatched_frames = camera.frames
            frames_watched = 0
            for _ in range(turns):
                samples, load = await _segment(daemon, segment)
                idle += samples
                cpu["idle"].append(load)
                unwatched_frames = camera.frames - unwatched_frames + frames_watched
                before = camera.frames
                viewer = await asyncio.create_subprocess_exec(
                    sys.executable, "-c", VIEWER, f"{url}/api/camera/stream",
                    str(segment + 1.0))
                await _until(_watching(camera, viewer))
                samples, load = await _segment(daemon, segment)
                watched += samples
                cpu["watched"].append(load)
                await viewer.wait()
                await _until(lambda: camera.viewers == 0)
                frames_watched += camera.frames - before
                unwatched_frames = camera.frames
            await asyncio.sleep(0.5)  # the frame in flight when the last viewer left
            idle_frames_before = camera.frames
            await asyncio.sleep(segment)
            frames_unwatched = camera.frames - idle_frames_before
    p99_idle, p99_watched = percentile_ms(idle, 99), percentile_ms(watched, 99)
    ratio = p99_watched / p99_idle if p99_idle > 0 else math.inf
    cpu_idle = 100 * sum(cpu["idle"]) / len(cpu["idle"])
    cpu_watched = 100 * sum(cpu["watched"]) / len(cpu["watched"])
    rate = frames_watched / (turns * segment)
    return [
        BenchResult(SUITE, "tick lateness p99, nobody watching", round(p99_idle, 4), "ms",
                    note="run --sim, camera on (640x480, 15 fps), in turns with a viewer"),
        BenchResult(SUITE, "tick lateness p99, one MJPEG viewer", round(p99_watched, 4),
                    "ms", note=f"{rate:.1f} frames/s streamed"),
        BenchResult(SUITE, "tick p99 streaming / nobody watching", round(ratio, 3), "x",
                    "<= 1.2", ratio <= 1.2, note=f"turns of {segment:g} s, same run"),
        BenchResult(SUITE, "daemon CPU, nobody watching", round(cpu_idle, 1), "% of a core"),
        BenchResult(SUITE, "daemon CPU, one MJPEG viewer (sim render + encode)",
                    round(cpu_watched, 1), "% of a core",
                    note="the simulator draws each frame; a Pi camera encodes in hardware"),
        BenchResult(SUITE, "frames made with nobody watching", frames_unwatched, "frames",
                    "0", frames_unwatched == 0, note=f"over {segment:g} s after the viewers"),
    ]


def run(quick: bool) -> list[BenchResult]:
    return [*render_costs(quick), *run_quietly(_ticks(quick))]
