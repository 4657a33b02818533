# Bench suite "foxglove": a 720-ray scan as JSON, cbor and cbor-raw frames; tick lateness with
# ten cbor-raw /scan clients, with and without the flight recorder, beside the idle figure.
from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import aiohttp
import numpy as np

from daemon.bench import BenchResult, bench_daemon, percentile_ms, run_quietly, scan_subscribers
from daemon.components.rosbridge.outbox import SharedMessage
from daemon.messages.convert import scan_msg
from daemon.messages.definitions import LASER_SCAN
from daemon.telemetry import SCAN
from sensors.scan import LaserScan

if TYPE_CHECKING:
    from daemon.app import Daemon

SUITE = "foxglove"
RAYS = 720
CLIENTS = 10


def synthetic_scan(stamp: float | None = None) -> LaserScan:
    rng = np.random.default_rng(7)
    ranges = rng.uniform(0.2, 10.0, RAYS).astype(np.float32)
    ranges[::40] = np.inf
    return LaserScan(time.time() if stamp is None else stamp, "laser", -math.pi, math.pi,
                     2 * math.pi / RAYS, 0.1 / RAYS, 0.1, 0.15, 12.0, ranges,
                     np.full(RAYS, 47, dtype=np.float32))


# -- encoding cost: one frame per encoding, built the way the server builds it --------------------


def _frame_makers(scan: LaserScan) -> dict[str, Callable[[], Any]]:
    def shared() -> SharedMessage:
        return SharedMessage("/scan", scan, scan_msg)

    return {"json": lambda: shared().frame("/scan"),
            "cbor": lambda: shared().binary_frame("cbor", "/scan", LASER_SCAN),
            "cbor-raw": lambda: shared().binary_frame("cbor-raw", "/scan", LASER_SCAN)}


def _costs_us(makers: dict[str, Callable[[], Any]], repeats: int) -> dict[str, float]:
    """Per frame, in µs: the median of ``repeats`` timed batches; the encodings take turns
    batch by batch, so all of them see the same machine load."""
    batch = 20
    samples: dict[str, list[float]] = {name: [] for name in makers}
    for _ in range(repeats):
        for name, make in makers.items():
            t0 = time.perf_counter()
            for _ in range(batch):
                make()
            samples[name].append((time.perf_counter() - t0) / batch * 1e6)
    return {name: statistics.median(values) for name, values in samples.items()}


def encoding_results(quick: bool) -> list[BenchResult]:
    scan = synthetic_scan()
    makers = _frame_makers(scan)
    costs = _costs_us(makers, 15 if quick else 60)
    sizes = {name: len(make()) for name, make in makers.items()}
    ratio = costs["cbor-raw"] / costs["json"]
    out = [BenchResult(SUITE, f"{RAYS}-ray scan frame, {name}", round(cost, 2), "µs",
                       note=f"{sizes[name]} bytes; convert + encode + frame, median")
           for name, cost in costs.items()]
    out.append(BenchResult(SUITE, "cbor-raw / JSON encoding cost", round(ratio, 3), "x",
                           "<= 0.1", ratio <= 0.1))
    return out


# -- tick lateness: the load side (a separate process, like real clients) ------------------------


async def generate_load(bridge_url: str, seconds: float, clients: int,
                        compression: str) -> dict[str, Any]:
    """``clients`` subscribers on /scan with ``compression``, reading for ``seconds``."""
    received = [0] * clients
    async with aiohttp.ClientSession() as session, contextlib.AsyncExitStack() as stack:
        sockets = await scan_subscribers(session, stack, bridge_url, clients,
                                         compression=compression)

        receiving = asyncio.Event()

        async def read(index: int, ws: aiohttp.ClientWebSocketResponse) -> None:
            async for message in ws:
                if message.type == aiohttp.WSMsgType.BINARY:
                    received[index] += 1
                    if min(received):
                        receiving.set()

        readers = [asyncio.create_task(read(i, ws)) for i, ws in enumerate(sockets)]
        await asyncio.wait_for(receiving.wait(), 20)  # every client subscribed and receiving
        print("ready", flush=True)
        await asyncio.sleep(seconds)
        for task in readers:
            task.cancel()
    return {"frames_received": received}


def worker_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m daemon.bench.foxglove")
    parser.add_argument("--bridge", required=True)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--clients", type=int, default=CLIENTS)
    parser.add_argument("--compression", default="cbor-raw")
    args = parser.parse_args(argv)
    out = asyncio.run(generate_load(args.bridge, args.seconds, args.clients, args.compression))
    print(json.dumps(out), flush=True)
    return 0


# -- tick lateness: the daemon side (this process) ------------------------------------------------


async def _load(bridge_url: str, seconds: float) -> asyncio.subprocess.Process:
    return await asyncio.create_subprocess_exec(
        sys.executable, "-m", "daemon.bench.foxglove", "--bridge", bridge_url,
        "--seconds", str(seconds), stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE)


async def _load_result(proc: asyncio.subprocess.Process) -> dict[str, Any]:
    out, err = await proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"bench worker failed: {err.decode()[-2000:]}")
    return dict(json.loads(out.decode().strip().splitlines()[-1]))


async def _publish_scans(daemon: Daemon, stop: asyncio.Event) -> None:
    """A 10 Hz lidar: a fresh 720-ray scan on the bus every 0.1 s."""
    while not stop.is_set():
        daemon.bus.publish(SCAN, synthetic_scan())
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), 0.1)


async def _lateness(daemon: Daemon, seconds: float) -> list[float]:
    """Tick lateness samples (s) over the next ``seconds``."""
    latency = daemon.latency
    latency.tick_late_ms.clear()
    await asyncio.sleep(seconds)
    return [ms / 1e3 for ms in latency.tick_late_ms]


async def _alternate(daemon: Daemon, recorder: Any, seconds: float,
                     segment: float) -> tuple[list[float], list[float]]:
    """Recorder off and on in turns of ``segment`` s, so both see the same machine load
    (``recorder``: the component, which listens to the bus only while recording)."""
    off: list[float] = []
    on: list[float] = []
    for i in range(max(2, round(seconds / segment))):
        recording = i % 2 == 1
        recorder.set_recording(recording)
        (on if recording else off).extend(await _lateness(daemon, segment))
    recorder.set_recording(False)
    return off, on


async def _tick_results(quick: bool) -> list[BenchResult]:
    seconds, segment = (3.0, 1.0) if quick else (15.0, 5.0)
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-") as tmp:
        # the recorder present but off: _alternate switches it
        record = f'[recorder]\nenabled = false\ndirectory = "{Path(tmp) / "rec"}"\n'
        async with bench_daemon(Path(tmp), record, serve_scan=True) as (daemon, url):
            stop = asyncio.Event()
            scans = asyncio.create_task(_publish_scans(daemon, stop))
            component = next(c for c in daemon.components if c.name == "recorder")
            recorder = component.recorder
            idle = await _lateness(daemon, seconds)
            worker = await _load(url, 2 * seconds + 1.0)
            assert worker.stdout is not None
            await asyncio.wait_for(worker.stdout.readline(), 20)  # "ready"
            clients, recording = await _alternate(daemon, component, 2 * seconds, segment)
            load = await _load_result(worker)
            written, dropped = recorder.written, recorder.dropped
            stop.set()
            await scans
    p99 = {name: percentile_ms(samples, 99) for name, samples in
           (("idle", idle), ("clients", clients), ("recording", recording))}
    added = p99["recording"] - p99["clients"]
    frames = load["frames_received"]
    return [
        BenchResult(SUITE, "tick lateness p99 idle", round(p99["idle"], 4), "ms",
                    note="same daemon, no clients, recorder off, scans on the bus at 10 Hz"),
        BenchResult(SUITE, f"tick lateness p99, {CLIENTS} cbor-raw /scan clients",
                    round(p99["clients"], 4), "ms", "<= 1", p99["clients"] <= 1.0,
                    note=f"{min(frames)}-{max(frames)} frames per client"),
        BenchResult(SUITE, "tick lateness p99, same clients + recorder",
                    round(p99["recording"], 4), "ms",
                    note=f"{written} messages written, {dropped} dropped"),
        BenchResult(SUITE, "tick lateness p99 added by recording", round(added, 4), "ms",
                    "<= 0.2", added <= 0.2,
                    note=f"recorder off/on in turns of {segment:g} s over {2 * seconds:g} s, "
                    "50 Hz tick"),
    ]


def run(quick: bool) -> list[BenchResult]:
    return [*encoding_results(quick), *run_quietly(_tick_results(quick))]


if __name__ == "__main__":
    sys.exit(worker_main(sys.argv[1:]))
