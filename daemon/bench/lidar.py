# Lidar decode benchmark: arbiterd vs the Python peers (rplidar-roboticia, pyrplidar), same bytes.
from __future__ import annotations

import importlib
import itertools
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from daemon.bench import BenchResult
from sensors.rplidar import synth
from sensors.rplidar.requests import Ans
from sensors.rplidar.streams import Samples, StreamParser

SUITE = "lidar"
TARGET_SAMPLES_PER_S = 2_000_000
TARGET_RATIO = 30.0
CHUNK = 4096  # bytes per read, like a busy serial port


@dataclass
class Streams:
    """Identical inputs for every decoder: the records and the whole byte stream."""

    nodes: list[bytes]
    node_stream: bytes
    capsules: list[bytes]
    capsule_stream: bytes


def make_streams(node_count: int, capsule_count: int, seed: int = 7) -> Streams:
    rng = np.random.default_rng(seed)
    angle = np.arange(node_count) * 1.83 % 360
    start = np.r_[False, np.diff(angle) < 0]
    dist = rng.uniform(150, 12000, node_count)
    nodes = synth.encode_nodes(angle, dist, np.full(node_count, 15), start)
    start_q6 = (np.arange(capsule_count + 1) * 1843) % 23040
    cap_dist = rng.uniform(150, 12000, (capsule_count + 1, 32))
    dtheta = rng.integers(0, 64, (capsule_count + 1, 32))
    caps = synth.encode_legacy(start_q6, cap_dist, dtheta, np.arange(capsule_count + 1) == 0)
    return Streams(
        [nodes[i:i + 5] for i in range(0, len(nodes), 5)],
        synth.STREAM_DESCRIPTORS[Ans.NODE].encode() + nodes,
        [caps[i:i + 84] for i in range(0, len(caps), 84)],
        synth.STREAM_DESCRIPTORS[Ans.CAPSULE].encode() + caps,
    )


# ---------------------------------------------------------------- decoders under test


def arbiterd_decode(stream: bytes) -> tuple[np.ndarray, np.ndarray]:
    parser = StreamParser()
    runs: list[Samples] = []
    for i in range(0, len(stream), CHUNK):
        runs += [e for e in parser.feed(stream[i:i + CHUNK]) if isinstance(e, Samples)]
    return (np.concatenate([r.angle_deg for r in runs]),
            np.concatenate([r.distance_mm for r in runs]))


def _peer(module: str) -> Any | None:
    try:
        return importlib.import_module(module)
    except ImportError:
        return None


def roboticia_nodes(rplidar: Any, nodes: list[bytes]) -> list[tuple[float, float]]:
    process = rplidar._process_scan
    return [process(raw)[2:] for raw in nodes]


def roboticia_express(rplidar: Any, capsules: list[bytes]) -> list[tuple[float, float]]:
    packets = [rplidar.ExpressPacket.from_string(raw) for raw in capsules]
    process = rplidar._process_express_scan
    out = []
    for packet, following in itertools.pairwise(packets):
        for trame in range(1, 33):
            out.append(process(packet, following.start_angle, trame)[2:])
    return out


def pyrplidar_nodes(proto: Any, nodes: list[bytes]) -> list[tuple[float, float]]:
    measurement = proto.PyRPlidarMeasurement
    return [(m.angle, m.distance) for m in (measurement(raw) for raw in nodes)]


def pyrplidar_express(proto: Any, capsules: list[bytes]) -> list[tuple[float, float]]:
    caps = [proto.PyRPlidarScanCapsule(raw) for raw in capsules]
    parse = proto.PyRPlidarScanCapsule._parse_capsule
    out = []
    for prev, cur in itertools.pairwise(caps):
        out += [(n.get_angle(), n.get_distance()) for n in parse(prev, cur)]
    return out


# ---------------------------------------------------------------- timing


def best_rate(decode: Callable[[], Any], samples: int, repeats: int) -> float:
    """Samples per second of the fastest of ``repeats`` runs."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        decode()
        best = min(best, time.perf_counter() - t0)
    return samples / best


def run(quick: bool) -> list[BenchResult]:
    """Decode identical standard-node and express-capsule streams with every decoder."""
    nodes, capsules = (40_000, 1_250) if quick else (400_000, 12_500)
    peer_share = 8 if quick else 20  # peers are ~100x slower: give them a slice of the input
    repeats = 3
    streams = make_streams(nodes, capsules)
    results: list[BenchResult] = []
    ours_std = best_rate(lambda: arbiterd_decode(streams.node_stream), nodes, repeats)
    ours_exp = best_rate(lambda: arbiterd_decode(streams.capsule_stream), capsules * 32, repeats)
    results.append(BenchResult(SUITE, "standard nodes, arbiterd", ours_std, "samples/s",
                               f">= {TARGET_SAMPLES_PER_S:,}", ours_std >= TARGET_SAMPLES_PER_S))
    results.append(BenchResult(SUITE, "express capsules, arbiterd", ours_exp, "samples/s"))
    node_slice = streams.nodes[:nodes // peer_share]
    cap_slice = streams.capsules[:capsules // peer_share + 1]
    peers = [("rplidar-roboticia", "rplidar", roboticia_nodes, roboticia_express, True),
             ("pyrplidar", "pyrplidar_protocol", pyrplidar_nodes, pyrplidar_express, False)]
    for label, module_name, std_fn, exp_fn, targeted in peers:
        module = _peer(module_name)
        if module is None:
            results.append(BenchResult(SUITE, f"{label} (not installed)", float("nan"), "",
                                       note="install the 'bench' extra to compare"))
            continue
        rate_std = best_rate(partial(std_fn, module, node_slice), len(node_slice), repeats)
        rate_exp = best_rate(partial(exp_fn, module, cap_slice), (len(cap_slice) - 1) * 32,
                             repeats)
        ratio_std, ratio_exp = ours_std / rate_std, ours_exp / rate_exp
        results += [
            BenchResult(SUITE, f"standard nodes, {label}", rate_std, "samples/s"),
            BenchResult(SUITE, f"standard speed-up vs {label}", ratio_std, "x",
                        f">= {TARGET_RATIO:g}" if targeted else "",
                        (ratio_std >= TARGET_RATIO) if targeted else None),
            BenchResult(SUITE, f"express capsules, {label}", rate_exp, "samples/s"),
            BenchResult(SUITE, f"express speed-up vs {label}", ratio_exp, "x"),
        ]
    return results


def main() -> None:
    for result in run(quick=True):
        print(f"{result.name:<42} {result.value:>14,.1f} {result.unit:<10} {result.target}")


if __name__ == "__main__":
    main()
