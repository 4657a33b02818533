# ROS 2 face benchmark: its CPU beside the same daemon without it, and /scan latency to rclpy.
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

from daemon.bench import BenchResult, free_port, percentile_ms
from daemon.bench.process import _cpu_seconds

SUITE = "ros2"
DOMAIN = 57
CPU_TARGET_PCT = 1.0
#: the stall supervisor's default: a longer gap zeroes the wheels
STALL_STOP_MS = 200.0
#: the flood: ten times [ros2] max_rate's default, 40 times a 50 Hz teleop
FLOOD_HZ = 2000.0
SIM = "[sim]\nlidar_rays = 720\nlidar_rate = 10.0\n"


def run(quick: bool) -> list[BenchResult]:
    """Two `arbiterd run --sim` (720-ray /scan at 10 Hz), one with [ros2] on and one rclpy
    subscriber of /scan and /odom (the Jazzy wheels of the extra have no tf2_msgs for /tf),
    one with it off, measured over the same windows."""
    try:
        import rclpy  # noqa: F401
    except ImportError:
        return [BenchResult(SUITE, "skipped", 0.0, "", note="rclpy is not installed (the "
                            "ros2-test extra, x86_64 Linux only)")]
    os.environ.update(ROS_DOMAIN_ID=str(DOMAIN), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    face = f"[ros2]\nenabled = true\ndomain_id = {DOMAIN}\ndiscovery = \"localhost\"\n"
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-ros2-") as tmp:
        on, _ = _start(Path(tmp) / "on", face)
        off, _ = _start(Path(tmp) / "off", "")
        try:
            results = _measure(on, off, 3 if quick else 6, 5.0)
        finally:
            _stop(on, off)
        commands, port = _start(Path(tmp) / "commands", face + "allow_commands = true\n")
        try:
            return results + _flood(port, 3.0 if quick else 10.0)
        finally:
            _stop(commands)


def _stop(*procs: subprocess.Popen[bytes]) -> None:
    for proc in procs:
        proc.terminate()
        proc.wait(15)


def _start(workdir: Path, extra: str) -> tuple[subprocess.Popen[bytes], int]:
    workdir.mkdir(parents=True)
    config = workdir / "arbiterd.toml"
    port = free_port()
    config.write_text(f"[http]\nhost = \"127.0.0.1\"\nport = {port}\n"
                      f"[rosbridge]\nhost = \"127.0.0.1\"\nport = {free_port()}\n" + SIM + extra)
    return subprocess.Popen([sys.executable, "-m", "daemon.cli", "run", "--sim", "--config",
                             str(config)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL), port


def _measure(on: subprocess.Popen[bytes], off: subprocess.Popen[bytes], windows: int,
             window_s: float) -> list[BenchResult]:
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import LaserScan

    rclpy.init()
    node = rclpy.create_node("bench_probe")
    latencies: list[float] = []
    rays: list[int] = []

    def on_scan(msg: LaserScan) -> None:
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        # the stamp is the revolution's first ray: the last came one scan_time later
        latencies.append(time.time() - stamp - msg.scan_time)
        rays.append(len(msg.ranges))

    node.create_subscription(LaserScan, "/scan", on_scan, qos_profile_sensor_data)
    node.create_subscription(Odometry, "/odom", lambda m: None, 10)
    try:
        _spin(node, lambda: len(rays) >= 10, 30.0)
        latencies.clear()
        extra: list[float] = []
        for _ in range(windows):
            a0, b0, t0 = _cpu_seconds(on.pid), _cpu_seconds(off.pid), time.monotonic()
            _spin(node, lambda: False, window_s)
            a1, b1, t1 = _cpu_seconds(on.pid), _cpu_seconds(off.pid), time.monotonic()
            extra.append(100.0 * ((a1 - a0) - (b1 - b0)) / (t1 - t0))
    finally:
        node.destroy_node()
        rclpy.shutdown()
    return _results(extra, latencies, rays)


def _spin(node: Any, done: Any, seconds: float) -> None:
    import rclpy

    end = time.monotonic() + seconds
    while time.monotonic() < end and not done():
        rclpy.spin_once(node, timeout_sec=0.05)


def _results(extra: list[float], latencies: list[float], rays: list[int]) -> list[BenchResult]:
    cpu = statistics.median(extra)
    note = f"{rays[-1] if rays else 0}-ray /scan at 10 Hz and /odom to one rclpy node"
    if not rays:  # discovery failed: the CPU figure would be of a face with no reader
        return [BenchResult(SUITE, "no /scan reached the rclpy node", 0.0, "", "scans", False,
                            "discovery failed; loopback-only discovery needs a network "
                            "namespace with only lo up: unshare -n sh -c 'ip link set lo up "
                            "&& arbiterd bench --only ros2' (docs/ros2.md)")]
    return [
        BenchResult(SUITE, "DDS face CPU (on minus off)", round(cpu, 2), "% of a core",
                    f"<= {CPU_TARGET_PCT:g}", cpu <= CPU_TARGET_PCT, note),
        BenchResult(SUITE, "/scan last ray -> rclpy callback, median",
                    round(percentile_ms(latencies, 50), 2), "ms",
                    note=f"{len(latencies)} scans; from the revolution's last ray (stamp + "
                    "scan_time): lidar decoding, the bus, CDR, DDS"),
        BenchResult(SUITE, "/scan last ray -> rclpy callback, p99",
                    round(percentile_ms(latencies, 99), 2), "ms"),
    ]


# -- a flood of DDS commands: the control tick beside it --------------------------------------


def _flood(port: int, seconds: float) -> list[BenchResult]:
    """One rclpy node publishes zero Twists on /cmd_vel at about FLOOD_HZ for ``seconds``,
    after a quiet window as long; the daemon's longest gap between control ticks after each."""
    import rclpy
    from geometry_msgs.msg import Twist

    rclpy.init()
    node = rclpy.create_node("bench_flood")
    publisher = node.create_publisher(Twist, "/cmd_vel", 10)

    def accepted() -> bool:
        publisher.publish(Twist())
        try:
            return bool(_health(port)["ros2"]["accepted"])
        except OSError:  # not listening yet
            return False

    try:
        _spin(node, accepted, 30.0)
        _spin(node, lambda: False, seconds)
        quiet = _health(port)["control"]["longest_stall_ms"]
        sent, end, twist = 0, time.monotonic() + seconds, Twist()
        while time.monotonic() < end:  # FLOOD_HZ, in bursts of 20 (the publisher shares
            for _ in range(20):        # this machine's cores with the daemon)
                publisher.publish(twist)
            sent += 20
            time.sleep(20 / FLOOD_HZ)
        after = _health(port)
    finally:
        node.destroy_node()
        rclpy.shutdown()
    face, control = after["ros2"], after["control"]
    gap = control["longest_stall_ms"]
    note = (f"{sent} samples in {seconds:g} s; the face took {face['received']}, accepted "
            f"{face['accepted']}, refused {face['refused']['overload']} as overload "
            f"([ros2] max_rate); stall stops {control['stall_stops']}")
    return [
        BenchResult(SUITE, "longest control-tick gap, quiet window", quiet, "ms",
                    note="in-run baseline: the same daemon before the flood"),
        BenchResult(SUITE, "longest control-tick gap, DDS /cmd_vel flood", gap, "ms",
                    f"< {STALL_STOP_MS:g} (no stall stop)",
                    gap < STALL_STOP_MS and control["stall_stops"] == 0, note),
    ]


def _health(port: int) -> dict[str, Any]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/health", timeout=5) as answer:
        return dict(json.load(answer)["components"])
