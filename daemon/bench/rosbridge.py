# Bench suite "rosbridge": WS stamped round trip vs a bare aiohttp echo, receipt->exec, tick load.
from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import json
import math
import sys
import tempfile
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import aiohttp
import numpy as np
from aiohttp import web

from daemon.bench import BenchResult, bench_daemon, free_port, run_quietly
from daemon.telemetry import SCAN

if TYPE_CHECKING:
    from daemon.app import Daemon

SUITE = "rosbridge"
SCAN_RAYS = 720


def _pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if values else math.nan


# -- the measuring side (a separate process, like a real client) ------------------------------


def _stamped_frame(seq: int) -> str:
    body = {"linear": {"x": 0.1}, "angular": {"z": 0.0}, "id": seq, "t_sent": time.time() * 1e3}
    return json.dumps({"op": "publish", "topic": "/stamped_cmd_vel",
                       "msg": {"data": json.dumps(body)}})


def _answers(text: str, topic: str, seq: int) -> bool:
    """Whether a received frame is the ``publish`` on ``topic`` whose String data carries the
    command ``seq``: the client's work on the answer, the same in both round trips."""
    reply = json.loads(text)
    return bool(reply.get("topic") == topic
                and json.loads(reply["msg"]["data"]).get("id") == seq)


async def _bridge_round_trip(ws: aiohttp.ClientWebSocketResponse, seq: int) -> float:
    frame = _stamped_frame(seq)
    t0 = time.perf_counter()
    await ws.send_str(frame)
    while not _answers((await ws.receive(timeout=5)).data, "/latency_reports", seq):
        pass
    return (time.perf_counter() - t0) * 1e3


async def _echo_round_trip(ws: aiohttp.ClientWebSocketResponse, seq: int) -> float:
    """The same frame to a bare aiohttp echo; its answer (the frame itself) is decoded and
    checked as the bridge's is, so the ratio compares the servers, not the clients' work."""
    frame = _stamped_frame(seq)
    t0 = time.perf_counter()
    await ws.send_str(frame)
    if not _answers((await ws.receive(timeout=5)).data, "/stamped_cmd_vel", seq):
        raise RuntimeError("the echo answered something else")
    return (time.perf_counter() - t0) * 1e3


async def measure_round_trips(echo_url: str, bridge_url: str, count: int) -> dict[str, Any]:
    """Interleaved round trips: echo and bridge alternate so both see the same machine load."""
    echo_ms: list[float] = []
    bridge_ms: list[float] = []
    async with aiohttp.ClientSession() as session, \
            session.ws_connect(echo_url) as echo, session.ws_connect(bridge_url) as bridge:
        await bridge.send_json({"op": "subscribe", "topic": "/latency_reports",
                                "type": "std_msgs/msg/String"})
        await bridge.send_json({"op": "advertise", "topic": "/stamped_cmd_vel",
                                "type": "std_msgs/msg/String"})
        for seq in range(count + 20):
            e = await _echo_round_trip(echo, seq)
            b = await _bridge_round_trip(bridge, seq)
            if seq >= 20:  # warm-up
                echo_ms.append(e)
                bridge_ms.append(b)
    return {"echo_ms": echo_ms, "bridge_ms": bridge_ms}


async def generate_load(bridge_url: str, windows: int, window_s: float, clients: int,
                        rate_hz: float) -> dict[str, Any]:
    """``windows`` windows of ``window_s``, idle and loaded in turns (idle first): loaded is
    ``clients`` subscribers on /scan and one /cmd_vel publisher at ``rate_hz``; idle, the same
    sockets stay open and unsubscribed. Prints ``idle`` or ``load`` as each window starts, and
    ``end`` after the last, for the daemon side to split its tick samples by."""
    received = [0] * clients
    sent = 0
    async with aiohttp.ClientSession() as session, contextlib.AsyncExitStack() as stack:
        sockets = [await stack.enter_async_context(session.ws_connect(bridge_url))
                   for _ in range(clients)]
        driver = await stack.enter_async_context(session.ws_connect(bridge_url))
        await driver.send_json({"op": "advertise", "topic": "/cmd_vel",
                                "type": "geometry_msgs/msg/Twist"})

        async def read(index: int, ws: aiohttp.ClientWebSocketResponse) -> None:
            async for message in ws:
                received[index] += isinstance(message.data, str) and '"/scan"' in message.data

        readers = [asyncio.create_task(read(i, ws)) for i, ws in enumerate(sockets)]
        for window in range(windows):
            loaded = window % 2 == 1
            for ws in sockets:
                await ws.send_json({"op": "subscribe" if loaded else "unsubscribe",
                                    "topic": "/scan"})
            print("load" if loaded else "idle", flush=True)
            period, t_next = 1.0 / rate_hz, time.monotonic()
            t_end = t_next + window_s
            while t_next < t_end:
                if loaded:
                    await driver.send_json({"op": "publish", "topic": "/cmd_vel", "msg": {
                        "linear": {"x": 0.2 if sent % 200 < 100 else 0.0},
                        "angular": {"z": 0.1}}})
                    sent += 1
                t_next += period
                await asyncio.sleep(max(0.0, t_next - time.monotonic()))
        print("end", flush=True)
        for task in readers:
            task.cancel()
    return {"scans_received": received, "commands_sent": sent}


def worker_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m daemon.bench.rosbridge")
    sub = parser.add_subparsers(dest="what", required=True)
    rtt = sub.add_parser("rtt")
    rtt.add_argument("--echo", required=True)
    rtt.add_argument("--bridge", required=True)
    rtt.add_argument("--count", type=int, default=300)
    load = sub.add_parser("load")
    load.add_argument("--bridge", required=True)
    load.add_argument("--windows", type=int, default=6)
    load.add_argument("--window", type=float, default=5.0)
    load.add_argument("--clients", type=int, default=10)
    load.add_argument("--rate", type=float, default=100.0)
    args = parser.parse_args(argv)
    if args.what == "rtt":
        out = asyncio.run(measure_round_trips(args.echo, args.bridge, args.count))
    else:
        out = asyncio.run(generate_load(args.bridge, args.windows, args.window, args.clients,
                                        args.rate))
    print(json.dumps(out), flush=True)
    return 0


# -- the daemon side (this process) -----------------------------------------------------------


async def _echo(request: web.Request) -> web.WebSocketResponse:
    ws = web.WebSocketResponse()
    await ws.prepare(request)
    async for message in ws:
        await ws.send_str(message.data)
    return ws


@contextlib.asynccontextmanager
async def echo_server() -> AsyncIterator[str]:
    app = web.Application()
    app.router.add_get("/", _echo)
    runner = web.AppRunner(app, access_log=None, handle_signals=False)
    await runner.setup()
    port = free_port()
    await web.TCPSite(runner, "127.0.0.1", port).start()
    try:
        yield f"ws://127.0.0.1:{port}/"
    finally:
        await runner.cleanup()


async def _worker(*args: str) -> dict[str, Any]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "daemon.bench.rosbridge", *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    out, err = await proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"bench worker failed: {err.decode()[-2000:]}")
    return dict(json.loads(out.decode().strip().splitlines()[-1]))


def _synthetic_scan() -> Any:
    from sensors.scan import LaserScan

    rng = np.random.default_rng(7)
    ranges = rng.uniform(0.2, 10.0, SCAN_RAYS).astype(np.float32)
    ranges[::40] = np.inf
    return LaserScan(time.time(), "laser", -math.pi, math.pi, 2 * math.pi / SCAN_RAYS, 0.0,
                     0.1, 0.1, 12.0, ranges, np.full(SCAN_RAYS, 47, dtype=np.float32))


async def _publish_scans(daemon: Daemon, stop: asyncio.Event) -> None:
    """A 10 Hz lidar: a revolution on the bus every 0.1 s, made beforehand (the lidar component
    converts its revolutions in its reader thread; the loop only publishes them)."""
    scan = _synthetic_scan()
    while not stop.is_set():
        daemon.bus.publish(SCAN, dataclasses.replace(scan, stamp=time.time()))
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), 0.1)


async def _tick_windows(daemon: Daemon, bridge_url: str, windows: int,
                        window_s: float) -> tuple[list[float], list[float], dict[str, Any]]:
    """Tick lateness (ms) in the idle and in the loaded windows of one load worker, whose
    windows alternate so that both halves see the same machine load."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "daemon.bench.rosbridge", "load", "--bridge", bridge_url,
        "--windows", str(windows), "--window", str(window_s),
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    assert proc.stdout is not None
    samples: dict[str, list[float]] = {"idle": [], "load": []}
    latency = daemon.latency
    current: str | None = None
    while True:
        line = (await asyncio.wait_for(proc.stdout.readline(), 60)).decode().strip()
        if current is not None:
            samples[current] += latency.tick_late_ms
        if line not in samples:
            break
        current = line
        latency.tick_late_ms.clear()
    out, err = await proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"bench worker failed: {err.decode()[-2000:]}")
    return samples["idle"], samples["load"], dict(json.loads(out.decode().splitlines()[-1]))


async def _run(quick: bool) -> list[BenchResult]:
    count, windows, window_s = (300, 6, 1.0) if quick else (2000, 20, 1.5)
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-") as tmp:
        async with echo_server() as echo_url, \
                bench_daemon(Path(tmp), serve_scan=True) as (daemon, bridge_url):
            latency = daemon.latency
            latency.exec_ms.clear()
            rtt = await _worker("rtt", "--echo", echo_url, "--bridge", bridge_url,
                                "--count", str(count))
            exec_ms = list(latency.exec_ms)
            stop = asyncio.Event()
            scans = asyncio.create_task(_publish_scans(daemon, stop))  # a 10 Hz lidar
            idle_ms, tick_ms, load = await _tick_windows(daemon, bridge_url, windows, window_s)
            stop.set()
            await scans
    return _results(rtt, exec_ms, idle_ms, tick_ms, load, windows * window_s / 2)


def _results(rtt: dict[str, Any], exec_ms: list[float], idle_ms: list[float],
             tick_ms: list[float], load: dict[str, Any], seconds: float) -> list[BenchResult]:
    bridge, echo = rtt["bridge_ms"], rtt["echo_ms"]
    ratio = _pct(bridge, 50) / _pct(echo, 50)
    exec_p99 = _pct(exec_ms, 99)
    tick_p99, idle_p99 = _pct(tick_ms, 99), _pct(idle_ms, 99)
    tick_ratio = tick_p99 / idle_p99
    scans = load["scans_received"]
    return [
        BenchResult(SUITE, "ws stamped round trip p50", _pct(bridge, 50), "ms",
                    note=f"send -> /latency_reports received, {len(bridge)} commands"),
        BenchResult(SUITE, "ws stamped round trip p99", _pct(bridge, 99), "ms"),
        BenchResult(SUITE, "bare aiohttp ws echo p50", _pct(echo, 50), "ms",
                    note="same frames, interleaved; both answers decoded the same way"),
        BenchResult(SUITE, "bare aiohttp ws echo p99", _pct(echo, 99), "ms"),
        BenchResult(SUITE, "round trip / echo at p50", ratio, "x", "<= 1.3", ratio <= 1.3),
        BenchResult(SUITE, "receipt -> exec p99", exec_p99, "ms", "<= 0.2", exec_p99 <= 0.2,
                    note=f"mock driver, {len(exec_ms)} commands"),
        BenchResult(SUITE, "tick lateness p99 idle", idle_p99, "ms",
                    note=f"same daemon, scans on the bus at 10 Hz, no subscriber: {len(idle_ms)} "
                    "ticks in the idle windows"),
        BenchResult(SUITE, "tick lateness p99 under load", tick_p99, "ms", "<= 1",
                    tick_p99 <= 1.0,
                    note=f"50 Hz tick, 10 clients on /scan ({SCAN_RAYS} rays, 10 Hz; "
                    f"{min(scans)}-{max(scans)} scans each), {load['commands_sent']} /cmd_vel "
                    f"at 100 Hz: {len(tick_ms)} ticks in {seconds:g} s of loaded windows"),
        BenchResult(SUITE, "tick lateness p99 under load / idle", tick_ratio, "x", "<= 1.5",
                    tick_ratio <= 1.5, note="idle and loaded windows in turns, same run"),
    ]


def run(quick: bool) -> list[BenchResult]:
    return run_quietly(_run(quick))


if __name__ == "__main__":
    sys.exit(worker_main(sys.argv[1:]))
