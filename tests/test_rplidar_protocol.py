# RPLIDAR parser and request encoder: vectors, SDK angle semantics, replies, resync.
from __future__ import annotations

import struct

import numpy as np
import pytest

from sensors.rplidar import requests as p
from sensors.rplidar import synth
from sensors.rplidar.requests import Ans
from sensors.rplidar.streams import Event, Samples, StreamParser


def samples_of(events: list[Event]) -> list[Samples]:
    return [e for e in events if isinstance(e, Samples)]


def concat(events: list[Event]) -> tuple[np.ndarray, np.ndarray]:
    runs = samples_of(events)
    if not runs:
        return np.empty(0), np.empty(0)
    return (np.concatenate([r.angle_deg for r in runs]),
            np.concatenate([r.distance_mm for r in runs]))


# ---------------------------------------------------------------- request encoder


@pytest.mark.parametrize(("frame", "expected"), [
    (p.express_scan(), "a5 82 05 00 00 00 00 00 22"),
    (p.express_scan(2), "a5 82 05 02 00 00 00 00 20"),
    (p.set_motor_pwm(660), "a5 f0 02 94 02 c1"),
    (p.set_motor_pwm(0), "a5 f0 02 00 00 57"),
    (p.get_lidar_conf(p.Conf.SCAN_MODE_COUNT), "a5 84 04 70 00 00 00 55"),
    (p.get_acc_board_flag(), "a5 ff 04 00 00 00 00 5e"),
    (p.hq_motor_speed(600), "a5 a8 02 58 02 55"),
    (p.stop(), "a5 25"), (p.reset(), "a5 40"), (p.scan(), "a5 20"), (p.force_scan(), "a5 21"),
    (p.get_info(), "a5 50"), (p.get_health(), "a5 52"), (p.get_samplerate(), "a5 59"),
])
def test_request_vectors(frame: bytes, expected: str) -> None:
    assert frame.hex(" ") == expected


def test_every_payload_command_round_trips_through_parse_request() -> None:
    frames = [p.express_scan(3, 1, 7), p.hq_scan(1), p.get_lidar_conf(p.Conf.SCAN_MODE_NAME, 2),
              p.set_lidar_conf(0x01, b"\x58\x02"), p.set_motor_pwm(1023), p.hq_motor_speed(0),
              p.get_acc_board_flag(), p.new_baudrate_confirm(256000)]
    for frame in frames:
        parsed = p.parse_request(frame)
        assert parsed is not None and parsed[0] == frame[1]
        assert len(parsed[1]) == frame[2]
    assert len(p.hq_scan()) == 3 + 33 + 1
    corrupted = p.express_scan()[:-1] + b"\x00"
    assert p.parse_request(corrupted) is None


def test_encoder_rejects_bad_arguments_with_names() -> None:
    with pytest.raises(ValueError, match=r"PWM must be 0\.\.1023"):
        p.set_motor_pwm(1024)
    with pytest.raises(ValueError, match="takes no payload"):
        p.request(p.Cmd.STOP, b"\x01")


# ---------------------------------------------------------------- single replies


def reply(data_type: int, body: bytes) -> bytes:
    return p.Descriptor(len(body), False, data_type).encode() + body


def test_banner_then_info_health_samplerate() -> None:
    banner = b"RP LIDAR System.\r\nFirmware Ver 1.29 - rtm, HW Ver 7\r\nModel: 18\r\n"
    serial = bytes(range(0x10, 0x20))
    stream = (banner + reply(Ans.INFO, bytes((0x18, 29, 1, 7)) + serial)
              + reply(Ans.HEALTH, b"\x02\x04\x00")
              + reply(Ans.SAMPLERATE, struct.pack("<HH", 508, 254)))
    parser = StreamParser()
    events = [e for i in range(len(stream)) for e in parser.feed(stream[i:i + 1])]
    info, health, rate = [e for e in events if not isinstance(e, p.Descriptor)]
    assert info == p.DeviceInfo(0x18, 1, 29, 7, serial.hex().upper())
    assert info.firmware == "1.29" and info.family == "A1" and info.model_name == "A1M8"
    assert health == p.Health(2, 0x0004)  # little-endian error code (peers read 0x0400)
    assert rate == p.SampleRate(508, 254)
    assert parser.stats.junk_bytes == len(banner)


def test_lidar_conf_replies() -> None:
    parser = StreamParser()
    events = parser.feed(
        reply(Ans.LIDAR_CONF, struct.pack("<IH", p.Conf.SCAN_MODE_COUNT, 5))
        + reply(Ans.LIDAR_CONF, struct.pack("<I", p.Conf.SCAN_MODE_NAME) + b"Express\x00")
        + reply(Ans.LIDAR_CONF, struct.pack("<II", p.Conf.SCAN_MODE_US_PER_SAMPLE, 254 << 8))
        + reply(Ans.LIDAR_CONF, struct.pack("<IB", p.Conf.SCAN_MODE_ANS_TYPE, 0x82))
        + reply(Ans.LIDAR_CONF, struct.pack("<II", p.Conf.SCAN_MODE_MAX_DISTANCE, 12 << 8)))
    confs = [e for e in events if isinstance(e, p.LidarConf)]
    assert [c.conf_type for c in confs] == [0x70, 0x7F, 0x71, 0x75, 0x74]
    assert confs[0].as_int() == 5
    assert confs[1].as_name() == "Express"
    assert confs[2].as_int() / 256 == 254
    assert confs[3].as_int() == 0x82
    assert confs[4].as_int() >> 8 == 12


def test_descriptor_lookalikes_in_junk_are_skipped() -> None:
    junk = b"\xa5\x5a\xff\xff\xff\xff\x99" + b"\xa5\x5a\x14\x00\x00\x40\x04"  # bad type, bad mode
    events = StreamParser().feed(junk + reply(Ans.HEALTH, b"\x00\x00\x00"))
    assert [e for e in events if isinstance(e, p.Health)] == [p.Health(0, 0)]


# ---------------------------------------------------------------- express angle semantics


def test_express_angles_follow_the_sdk_when_dtheta_has_bit5_set() -> None:
    """Hand-computed with the SDK's fixed-point rules (unsigned dθ, k = 0..31).

    Capsule A starts at 0°, capsule B at 32°: Δ_q8 = 8192, step = 65536 q16 = 1° per sample.
    k=0, dθ=56 (7°, bit 5 set): (0 - 56·8192) >> 10 = -448 → 22592 q6 = 353.0°
        (a sign-bit reading gives a positive offset instead: Roboticia/RPLidar#4).
    k=1, dθ=33 (4.125°, bit 5 set): (65536 - 270336) >> 10 = -200 → 356.875°
    k=2, dθ=0: 131072 >> 10 = 128 → 2.0°
    k=3, dθ=63: (196608 - 516096) >> 10 = -312 → 355.125°
    """
    dtheta = np.zeros((2, 32), dtype=int)
    dtheta[0, :4] = [56, 33, 0, 63]
    dist = np.full((2, 32), 1000)
    raw = synth.STREAM_DESCRIPTORS[Ans.CAPSULE].encode() + synth.encode_legacy(
        [0, 32 * 64], dist, dtheta, [True, False])
    angle, distance = concat(StreamParser().feed(raw))
    assert len(angle) == 32  # capsule B waits for its successor
    assert angle[:4].tolist() == [353.0, 356.875, 2.0, 355.125]
    assert angle[4] == 4.0 and angle[31] == 31.0
    assert (distance == 1000).all()


def test_express_angle_floor_semantics_with_fractional_step() -> None:
    """Start 1843 q6 → Δ_q8 = 7372, step = 58976 q16; k=5, dθ=40 (bit 5 set, 5°):
    (5·58976 - 40·8192) >> 10 = -32800 >> 10 = -33 (arithmetic shift floors) → 23007 q6."""
    dtheta = np.zeros((2, 32), dtype=int)
    dtheta[0, 5] = 40
    raw = synth.STREAM_DESCRIPTORS[Ans.CAPSULE].encode() + synth.encode_legacy(
        [0, 1843], np.full((2, 32), 500), dtheta, [True, False])
    angle, _ = concat(StreamParser().feed(raw))
    assert angle[5] == 23007 / 64
    assert angle[6] == (6 * 58976 >> 10) / 64


def test_sync_bit_mid_stream_is_an_encoder_reset() -> None:
    starts = [0, 1843, 3686, 5529, 7372]
    raw = synth.STREAM_DESCRIPTORS[Ans.CAPSULE].encode() + synth.encode_legacy(
        starts, np.full((5, 32), 700), np.zeros((5, 32)), [True, False, False, True, False])
    events = StreamParser().feed(raw)
    kinds = [type(e).__name__ for e in events]
    # capsules 0,1 decode (paired with 1,2); capsule 2 is dropped by the reset at 3; 3 waits on 4.
    assert kinds == ["Descriptor", "Samples", "EncoderReset", "Samples"]
    assert [len(s) for s in samples_of(events)] == [64, 32]


def test_dense_distances_are_little_endian_and_unoffset() -> None:
    dist = np.arange(80).reshape(2, 40) * 100 + 258  # 258 = 0x0102: byte order matters
    raw = synth.STREAM_DESCRIPTORS[Ans.DENSE_CAPSULE].encode() + synth.encode_dense(
        [0, 40 * 64], dist, [True, False])
    angle, distance = concat(StreamParser().feed(raw))
    assert distance.tolist() == dist[0].tolist()
    assert angle.tolist() == [float(k) for k in range(40)]


def test_ultra_capsule_offsets_and_predictions() -> None:
    dist = np.full((3, 96), 1000)
    dist[0, 1] = 1006  # prediction off the major: p1 = 3 at level 1
    dist[0, 2] = 0  # no return: invalid prediction marker
    raw = synth.STREAM_DESCRIPTORS[Ans.ULTRA_CAPSULE].encode() + synth.encode_ultra(
        [0, 96 * 64, 192 * 64], dist, [True, False, False], next_first_mm=1000)
    angle, distance = concat(StreamParser().feed(raw))
    assert len(distance) == 192
    assert distance[:4].tolist() == [1000, 1006, 0, 1000]
    # 1 m: offset ≈ 6.66° (reference table); q16 accumulator, >> 10 to q6
    assert angle[0] == pytest.approx(360 - 6.66, abs=0.02)
    assert angle[2] == pytest.approx(360 + 2 - 7.5, abs=0.02)  # no return (< 50 mm): 7.5°


def test_standard_stream_resyncs_after_a_lost_byte() -> None:
    n = 300
    angle = np.arange(n) * 1.2 % 360
    start = np.r_[True, np.diff(angle) < 0]
    body = synth.encode_nodes(angle, np.full(n, 2000.0), np.full(n, 15), start)
    broken = body[:503] + body[504:]  # node 100 loses a byte
    parser = StreamParser()
    got, _ = concat(parser.feed(synth.STREAM_DESCRIPTORS[Ans.NODE].encode() + broken))
    assert parser.resyncs == 1
    got_q6 = set(np.rint(got * 64).astype(int).tolist())
    want = np.rint(angle * 64).astype(int)
    # the nodes on either side of the damage may be dropped (junk may reach into them); the
    # last node waits for its successor to be judged
    assert set(want[:99].tolist()) <= got_q6 and set(want[102:-1].tolist()) <= got_q6
    assert got_q6 <= set(want.tolist()) and len(got) >= n - 4
