# Revolution assembler and LaserScan conversion.
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from sensors.rplidar import synth
from sensors.rplidar.assembler import (
    Revolution,
    RevolutionAssembler,
    ScanGeometry,
    to_laser_scan,
)
from sensors.rplidar.requests import Ans
from sensors.rplidar.streams import EncoderReset, Samples, StreamParser


def node_stream(turns: float, per_turn: int, first_deg: float = 100.0) -> tuple[bytes, np.ndarray]:
    n = int(turns * per_turn)
    angle = (first_deg + np.arange(n) * 360.0 / per_turn) % 360
    start = np.r_[False, np.diff(angle) < 0]
    dist = 1000 + np.arange(n) % per_turn  # distance encodes the index within a turn
    body = synth.encode_nodes(angle, dist, np.full(n, 15), start)
    return synth.STREAM_DESCRIPTORS[Ans.NODE].encode() + body, dist


def test_only_whole_revolutions_are_published_whatever_the_chunking() -> None:
    stream, _ = node_stream(3.5, 200)
    for chunk in (1, 7, 333, len(stream)):
        parser, asm = StreamParser(), RevolutionAssembler(sample_period=0.001)
        revs: list[Revolution] = []
        for i in range(0, len(stream), chunk):
            revs += asm.feed(parser.feed(stream[i:i + chunk]), t_arrival=float(i))
        # starts at 100°, wraps at 0° three times: turns 1 and 2 are whole, the rest partial
        assert len(revs) == 2, chunk
        for rev in revs:
            assert len(rev) == 200
            assert rev.angle_deg[0] == pytest.approx(0.0, abs=1.0)
            assert np.all(np.diff(rev.angle_deg) > 0)


def test_first_ray_timestamp_and_scan_time() -> None:
    parser, asm = StreamParser(), RevolutionAssembler(sample_period=0.001)
    stream, _ = node_stream(3.2, 100, first_deg=0.5)
    revs: list[Revolution] = []
    per_node = 5
    header = 7
    for k in range(0, 320):  # one node per chunk, arriving 1 ms apart
        chunk = stream[header + k * per_node: header + (k + 1) * per_node]
        if k == 0:
            chunk = stream[:header] + chunk
        revs += asm.feed(parser.feed(chunk), t_arrival=100.0 + k * 0.001)
    assert len(revs) == 2
    assert revs[0].t == pytest.approx(100.0 + 100 * 0.001, abs=1e-9)
    assert revs[0].scan_time == pytest.approx(0.1, abs=1e-9)


def test_encoder_reset_abandons_the_revolution_in_progress() -> None:
    asm = RevolutionAssembler(min_samples=1)  # toy turns of 4 samples

    def run(angles: list[float], new_rev: list[bool]) -> Samples:
        n = len(angles)
        return Samples(Ans.CAPSULE, np.array(angles), np.full(n, 500.0),
                       np.full(n, 47, dtype=np.uint8), np.array(new_rev))

    assert asm.feed([run([0, 90, 180], [True, False, False])], 1.0) == []
    assert asm.feed([EncoderReset(), run([270, 0, 90], [False, True, False])], 2.0) == []
    revs = asm.feed([run([180, 270, 0], [False, False, True])], 3.0)
    assert len(revs) == 1 and revs[0].angle_deg.tolist() == [0, 90, 180, 270]
    assert asm.discarded == 1


def test_overlong_revolution_is_dropped() -> None:
    asm = RevolutionAssembler(max_samples=10)
    n = 30
    samples = Samples(Ans.NODE, np.linspace(0, 359, n), np.full(n, 1.0),
                      np.zeros(n, dtype=np.uint8), np.r_[True, np.zeros(n - 1, bool)])
    end = Samples(Ans.NODE, np.array([0.0]), np.array([1.0]), np.zeros(1, np.uint8),
                  np.array([True]))
    assert asm.feed([samples, end], 1.0) == []


def revolution(angles: list[float], dist_mm: list[float]) -> Revolution:
    return Revolution(12.5, 0.1, np.array(angles, dtype=float), np.array(dist_mm, dtype=float),
                      np.full(len(angles), 15, dtype=np.uint8))


def test_laser_scan_is_counter_clockwise_with_inf_for_no_return() -> None:
    rev = revolution([0.0, 90.0, 180.0, 270.0], [1000, 2000, 0, 4000])
    scan = to_laser_scan(rev, ScanGeometry(frame_id="base_laser"))
    # device 90° clockwise = -90° in ROS; sorted ascending from -180°
    assert scan.angle_min == pytest.approx(-math.pi)
    assert scan.angle_increment == pytest.approx(math.pi / 2)
    assert scan.ranges.tolist() == [float("inf"), 2.0, 1.0, 4.0]
    assert scan.frame_id == "base_laser" and scan.stamp == 12.5
    assert scan.time_increment == pytest.approx(0.1 / 4)
    payload = scan.to_json()
    json.dumps(payload, allow_nan=False)
    assert payload["ranges"][0] is None and payload["ranges"][1] == 2.0


def test_inverted_mount_keeps_device_direction() -> None:
    rev = revolution([10.0, 90.0], [1000, 2000])
    scan = to_laser_scan(rev, ScanGeometry(inverted=True))
    assert scan.angle_min == pytest.approx(math.radians(10))
    assert scan.ranges.tolist() == [1.0, 2.0]


def test_fixed_bins_take_the_nearest_return() -> None:
    rev = revolution([0.2, 0.4, 359.6, 45.0, 200.0], [3000, 2000, 2500, 1000, 0])
    scan = to_laser_scan(rev, ScanGeometry(bins=360))
    assert len(scan.ranges) == 360 and scan.angle_increment == pytest.approx(math.radians(1))
    zero = 180  # bin of angle 0 (angle_min = -180°)
    assert scan.ranges[zero] == pytest.approx(2.0)
    assert scan.ranges[zero - 45] == pytest.approx(1.0)  # device 45° clockwise → -45°
    assert np.isinf(scan.ranges).sum() == 358


def test_cli_json_has_null_for_missing_returns() -> None:
    payload = revolution([1.0, 2.0], [1500, 0]).to_cli_json()
    assert payload == {"t": 12.5, "angles_deg": [1.0, 2.0], "ranges_m": [1.5, None],
                       "quality": [15, 15]}
