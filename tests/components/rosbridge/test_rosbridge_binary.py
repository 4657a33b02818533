# CDR and CBOR encodings checked against an independent ROS 2 CDR decoder (mcap_ros2) and cbor2.
from __future__ import annotations

import json
import logging
import math
import struct
from typing import Any

import cbor2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap_ros2._dynamic import generate_dynamic

from daemon.components.rosbridge import binary
from daemon.components.rosbridge.outbox import SharedMessage, SubscribeOptions, TopicQueue
from daemon.messages import cbor, cdr, scans
from daemon.messages.convert import log_msg, odometry_msg, scan_msg, tf_msg
from daemon.messages.definitions import LASER_SCAN, LOG, ODOMETRY, TF_MESSAGE
from daemon.messages.msgtypes import default_message, full_text, known_types
from daemon.telemetry import OdomSample, Transform
from sensors.scan import LaserScan
from tests.support.compare import close_to


def decode(type_name: str, data: bytes) -> Any:
    """mcap_ros2's own CDR reader, built from the definition rosapi advertises."""
    return generate_dynamic(type_name, full_text(type_name))[type_name](data)


def odom_sample(x: float = 1.25, theta: float = 0.3) -> OdomSample:
    return OdomSample(1700000000.125, "odom", "base_link", x, -2.5, theta, 0.4, -0.5,
                      [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], [1.0, 1.0, 1.0, 1.0, 1.0, 2.0])


def laser_scan(rays: int = 720) -> LaserScan:
    ranges = np.linspace(0.15, 11.0, rays, dtype=np.float32)
    ranges[::7] = np.inf
    return LaserScan(stamp=1700000001.5, frame_id="laser", angle_min=-math.pi,
                     angle_max=math.pi, angle_increment=2 * math.pi / max(rays, 1),
                     time_increment=1e-4, scan_time=0.1, range_min=0.15, range_max=12.0,
                     ranges=ranges, intensities=np.full(rays, 47.0, dtype=np.float32))


@pytest.mark.parametrize("type_name", known_types())
def test_every_type_encodes_as_its_advertised_definition_decodes(type_name: str) -> None:
    data = cdr.encode(type_name, default_message(type_name))
    assert data[:4] == b"\x00\x01\x00\x00"
    decoded = decode(type_name, data)
    assert decoded is not None


def test_string_bytes_are_exactly_ros2_cdr() -> None:
    assert cdr.encode("std_msgs/msg/String", {"data": "hi"}) == (
        b"\x00\x01\x00\x00" + struct.pack("<I", 3) + b"hi\x00")


def test_alignment_counts_from_after_the_header() -> None:
    # Bool then nothing; Log: int32/uint32 stamp, uint8 level, strings (align 4), uint32 line
    data = cdr.encode(LOG, {"stamp": {"sec": 1, "nanosec": 2}, "level": 20, "name": "a",
                            "msg": "bc", "file": "", "function": "f", "line": 7})
    payload = data[4:]
    assert payload[:8] == struct.pack("<iI", 1, 2)
    assert payload[8] == 20 and payload[9:12] == b"\x00\x00\x00"  # padding to 4 for a string
    decoded = decode(LOG, data)
    assert (decoded.level, decoded.name, decoded.msg, decoded.function, decoded.line) == (
        20, "a", "bc", "f", 7)


def test_odometry_round_trips_with_its_covariances() -> None:
    msg = odometry_msg(odom_sample())
    decoded = decode(ODOMETRY, cdr.encode(ODOMETRY, msg))
    assert (decoded.header.stamp.sec, decoded.header.stamp.nanosec) == (1700000000, 125000000)
    assert decoded.header.frame_id == "odom" and decoded.child_frame_id == "base_link"
    assert decoded.pose.pose.position.x == 1.25 and decoded.pose.pose.position.y == -2.5
    assert close_to(decoded.pose.pose.orientation.z, math.sin(0.15), 1e-12)
    assert decoded.twist.twist.linear.x == 0.4 and decoded.twist.twist.angular.z == -0.5
    assert list(decoded.pose.covariance) == msg["pose"]["covariance"]
    assert list(decoded.twist.covariance) == msg["twist"]["covariance"]


def test_tf_message_round_trips() -> None:
    message = tf_msg((Transform.of_odometry(odom_sample()),))
    decoded = decode(TF_MESSAGE, cdr.encode(TF_MESSAGE, message))
    (transform,) = decoded.transforms
    assert transform.child_frame_id == "base_link"
    assert transform.transform.translation.x == 1.25


def test_scan_arrays_keep_float32_ranges_and_inf() -> None:
    scan = laser_scan()
    decoded = decode(LASER_SCAN, cdr.encode(LASER_SCAN, scans.scan_arrays(scan)))
    assert np.array_equal(np.asarray(decoded.ranges, dtype=np.float32), scan.ranges)
    assert np.isinf(decoded.ranges[0]) and len(decoded.intensities) == 720
    assert close_to(decoded.angle_increment, 2 * math.pi / 720, 1e-7)


def test_the_json_shaped_scan_encodes_to_the_same_values() -> None:
    scan = laser_scan(360)
    from_json = decode(LASER_SCAN, cdr.encode(LASER_SCAN, scan_msg(scan)))
    from_arrays = decode(LASER_SCAN, cdr.encode(LASER_SCAN, scans.scan_arrays(scan)))
    finite = np.isfinite(scan.ranges)
    assert np.allclose(np.asarray(from_json.ranges)[finite], np.asarray(from_arrays.ranges)[finite],
                       atol=1e-4)
    assert np.isnan(np.asarray(from_json.ranges)[~finite]).all()  # JSON null -> NaN


def test_log_line_round_trips() -> None:
    record = logging.LogRecord("arbiterd.control", logging.WARNING, "/x/loop.py", 42,
                               "e-stop engaged: %s", ("http",), None, "engage_estop")
    decoded = decode(LOG, cdr.encode(LOG, log_msg(record)))
    assert (decoded.level, decoded.msg, decoded.line) == (30, "e-stop engaged: http", 42)


def test_a_wrong_fixed_array_length_is_an_error_naming_the_field() -> None:
    msg = odometry_msg(odom_sample())
    msg["pose"]["covariance"] = [0.0] * 35
    with pytest.raises(cdr.CdrError, match=r"pose\.covariance: expected exactly 36"):
        cdr.encode(ODOMETRY, msg)


@settings(max_examples=50, deadline=None)
@given(st.floats(allow_nan=False, width=64), st.floats(-10, 10), st.text(max_size=20))
def test_odometry_property(x: float, theta: float, frame: str) -> None:
    sample = odom_sample(x, theta)
    msg = odometry_msg(sample)
    msg["header"]["frame_id"] = frame
    decoded = decode(ODOMETRY, cdr.encode(ODOMETRY, msg))
    assert decoded.pose.pose.position.x == x and decoded.header.frame_id == frame


# -- cbor and cbor-raw -----------------------------------------------------------------------------


def test_cbor_values_use_typed_arrays_bytes_and_plain_lists() -> None:
    scan = laser_scan()
    values = cbor2.loads(cbor.cbor_msg(LASER_SCAN, scans.scan_arrays(scan)))
    assert values["header"]["stamp"] == {"sec": 1700000001, "nanosec": 500000000}
    tag = values["ranges"]
    assert isinstance(tag, cbor2.CBORTag) and tag.tag == 85
    assert np.array_equal(np.frombuffer(tag.value, "<f4"), scan.ranges)
    odom = cbor2.loads(cbor.cbor_msg(ODOMETRY, odometry_msg(odom_sample())))
    assert isinstance(odom["pose"]["covariance"], list) and len(odom["pose"]["covariance"]) == 36
    raw = cbor2.loads(cbor.cbor_msg("std_msgs/msg/UInt8MultiArray", {
        "layout": {"dim": [], "data_offset": 0}, "data": [1, 2, 255]}))
    assert raw["data"] == b"\x01\x02\xff"


def test_cbor_values_of_a_json_scan_turn_null_into_nan() -> None:
    scan = laser_scan(10)
    values = cbor.cbor_values(LASER_SCAN, scan_msg(scan))
    ranges = np.frombuffer(values["ranges"].value, "<f4")
    assert np.isnan(ranges[0]) and close_to(float(ranges[1]), float(scan.ranges[1]), 1e-4)


def test_cbor_raw_frame_is_the_rosbridge_publish_op() -> None:
    data = cdr.encode("std_msgs/msg/String", {"data": "hello"})
    frame = binary.publish_frame("/chatter", binary.cbor_raw_msg(data, 1700000002.25))
    assert cbor2.loads(frame) == {"op": "publish", "topic": "/chatter",
                                  "msg": {"secs": 1700000002, "nsecs": 250000000,
                                          "bytes": data}}


def test_cbor_frame_is_the_rosbridge_publish_op() -> None:
    frame = binary.publish_frame("odom", cbor.cbor_msg(ODOMETRY, odometry_msg(odom_sample())))
    body = cbor2.loads(frame)
    assert body["op"] == "publish" and body["topic"] == "odom"
    assert body["msg"]["pose"]["pose"]["position"]["x"] == 1.25


# -- shared frames and merged subscriptions (outbox) -----------------------------------------------


def test_a_message_is_encoded_once_per_encoding_and_the_frame_shared() -> None:
    calls: list[str] = []

    def convert(sample: OdomSample) -> dict[str, Any]:
        calls.append("odom")
        return odometry_msg(sample)

    shared = SharedMessage("/odom", odom_sample(), convert)
    first = shared.binary_frame("cbor-raw", "/odom", ODOMETRY)
    assert shared.binary_frame("cbor-raw", "/odom", ODOMETRY) is first
    other_spelling = shared.binary_frame("cbor-raw", "odom", ODOMETRY)
    assert cbor2.loads(other_spelling)["msg"] == cbor2.loads(first)["msg"]
    shared.binary_frame("cbor", "/odom", ODOMETRY)
    shared.frame("/odom")
    assert calls == ["odom", "odom", "odom"]  # once for cbor-raw, cbor and JSON, never per client
    body = cbor2.loads(first)
    assert decode(ODOMETRY, body["msg"]["bytes"]).pose.pose.position.x == 1.25


def test_a_robot_scan_takes_the_array_path_and_a_relayed_dict_its_own() -> None:
    scan = laser_scan()
    raw = cbor2.loads(SharedMessage("/scan", scan, scan_msg).binary_frame(
        "cbor-raw", "/scan", LASER_SCAN))
    ranges = np.asarray(decode(LASER_SCAN, raw["msg"]["bytes"]).ranges, dtype=np.float32)
    assert np.array_equal(ranges, scan.ranges)  # float32 as measured, not the JSON rounding
    relayed = SharedMessage("/chatter", {"data": "hi"})
    assert cbor2.loads(relayed.binary_frame("cbor", "/chatter", "std_msgs/msg/String"))[
        "msg"] == {"data": "hi"}


def test_subscriptions_merge_compression_by_rosbridge_precedence() -> None:
    queue = TopicQueue("/odom", "/odom", state=True)
    queue.set_entry("a", SubscribeOptions(compression="none"))
    queue.set_entry("b", SubscribeOptions(compression="cbor-raw"))
    queue.set_entry("c", SubscribeOptions(compression="cbor"))
    assert queue.options.compression == "cbor-raw"
    queue.remove_entry("b")
    assert queue.options.compression == "cbor"


def test_the_bench_measures_real_frames_of_one_scan() -> None:
    from daemon.bench.foxglove import _frame_makers, synthetic_scan

    makers = _frame_makers(synthetic_scan(1700000000.0))
    as_json = json.loads(makers["json"]())["msg"]
    as_raw = decode(LASER_SCAN, cbor2.loads(makers["cbor-raw"]())["msg"]["bytes"])
    as_cbor = cbor2.loads(makers["cbor"]())["msg"]
    assert len(as_json["ranges"]) == len(as_raw.ranges) == 720
    assert as_cbor["header"] == as_json["header"] == {
        "stamp": {"sec": 1700000000, "nanosec": 0}, "frame_id": "laser"}


@settings(max_examples=40, deadline=None)
@given(st.text(max_size=9), st.integers(0, 50), st.floats(1e9, 2e9))
def test_the_scan_fast_path_writes_what_the_generic_encoder_writes(
        frame_id: str, rays: int, t: float) -> None:
    scan = laser_scan(rays)
    scan.frame_id, scan.stamp = frame_id, t
    assert scans.scan_cdr(scan) == cdr.encode(LASER_SCAN, scans.scan_arrays(scan))


def test_cbor_heads_of_every_width() -> None:
    for value in (0, 23, 24, 255, 256, 65535, 65536, 2**32 - 1, 2**32):
        data = bytes(value % 7 for _ in range(min(value, 70000)))
        raw = binary.cbor_raw_msg(data, value + 0.5)
        assert cbor2.loads(raw) == {"secs": value, "nsecs": 500000000, "bytes": data}
