# Pure rosbridge pieces: type names, checking, encoding, fragments, queues, typedefs, budgets.
from __future__ import annotations

import contextlib
import json
import logging
import math
import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from daemon.components.rosbridge import codec
from daemon.components.rosbridge.codec import (
    FRAGMENT_COST,
    Defragmenter,
    FragmentLimits,
    ProtocolError,
    decode_frame,
    encode,
    fragments,
    publish_frame,
    request_id,
    topic_name,
)
from daemon.components.rosbridge.limits import RateLimitedLog, TokenBucket
from daemon.components.rosbridge.outbox import (
    EVENT_QUEUE,
    SharedMessage,
    SubscribeOptions,
    TopicQueue,
)
from daemon.messages import msgtypes
from daemon.messages.convert import odometry_msg, scan_msg
from daemon.messages.msgtypes import MessageError, check_message, full_text, normalize_type
from daemon.telemetry import OdomSample
from sensors.scan import LaserScan
from tests.support.rosbridge import FakeScan


@pytest.mark.parametrize(("given", "expected"), [
    ("geometry_msgs/Twist", "geometry_msgs/msg/Twist"),
    ("geometry_msgs/msg/Twist", "geometry_msgs/msg/Twist"),
    ("rcl_interfaces/msg/Log", "rcl_interfaces/msg/Log"),
])
def test_type_names_normalise_to_the_long_form(given: str, expected: str) -> None:
    assert normalize_type(given) == expected


@pytest.mark.parametrize("bad", ["", "/", "bad", "better/", "/better", "this\\isbad",
                                 "a/srv/B", 42])
def test_bad_type_names_are_refused(bad: object) -> None:
    with pytest.raises(MessageError):
        normalize_type(bad)


def test_service_type_names() -> None:
    assert normalize_type("std_srvs/SetBool", "srv") == "std_srvs/srv/SetBool"


def test_every_definition_parses_and_resolves() -> None:
    for name in msgtypes.known_types():
        spec = msgtypes.get_type(name)
        for field in spec.fields:
            assert field.is_primitive or msgtypes.has_type(field.base), (name, field)


def test_missing_fields_take_defaults_and_quaternion_w_is_one() -> None:
    msg = check_message("geometry_msgs/msg/Pose", {"position": {"x": 1}})
    assert msg == {"position": {"x": 1.0, "y": 0.0, "z": 0.0},
                   "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}


@pytest.mark.parametrize(("type_name", "msg", "fragment"), [
    ("geometry_msgs/msg/Twist", {"linear": {"x": "fast"}}, "msg.linear.x: expected float64"),
    ("geometry_msgs/msg/Twist", {"linear": {"q": 1}}, "does not have a field 'q'"),
    ("geometry_msgs/msg/Twist", {"linear": [1, 2, 3]}, "msg.linear: expected an object"),
    ("std_msgs/msg/Bool", {"data": 1}, "msg.data: expected bool"),
    ("std_msgs/msg/Int32", {"data": 2**31}, "out of range for int32"),
    ("std_msgs/msg/Int32", {"data": 1.5}, "expected int32"),
    ("std_msgs/msg/MultiArrayDimension", {"size": -1}, "out of range for uint32"),
    ("geometry_msgs/msg/PoseWithCovariance", {"covariance": [0.0] * 35},
     "expected exactly 36 items"),
    ("std_msgs/msg/UInt8MultiArray", {"data": [1, 256]}, "msg.data[1]: 256 is out of range"),
    ("std_msgs/msg/UInt8MultiArray", {"data": "***"}, "not valid base64"),
    ("std_msgs/msg/Header", {"stamp": {"sec": 1, "usec": 2}},
     "msg.stamp: expected {sec, nanosec}, {secs, nsecs} or {sec, nsec}, got fields"),
    ("std_msgs/msg/Header", {"stamp": {"sec": 1, "nsec": 2, "nanosec": 2}},
     "msg.stamp: nanosec and nsec are the same field; give one"),
    ("std_msgs/msg/Header", {"stamp": {"sec": 1, "nsec": -1}}, "msg.stamp.nsec: -1 is out of"),
    ("std_msgs/msg/Header", {"stamp": 5}, "msg.stamp: expected {sec, nanosec}"),
    ("std_msgs/msg/String", "hello", "msg: expected an object"),
])
def test_bad_messages_name_the_field(type_name: str, msg: object, fragment: str) -> None:
    with pytest.raises(MessageError, match=None) as info:
        check_message(type_name, msg)
    assert fragment in str(info.value)


def test_ros1_time_and_now_are_accepted_and_ros2_time_comes_out() -> None:
    header = check_message("std_msgs/msg/Header", {"stamp": {"secs": 5, "nsecs": 7}})
    assert header["stamp"] == {"sec": 5, "nanosec": 7}
    now = check_message("std_msgs/msg/Header", {"stamp": "now"})["stamp"]
    assert now["sec"] > 1_600_000_000 and 0 <= now["nanosec"] < 10**9
    assert check_message("std_msgs/msg/Header", {})["stamp"]["sec"] > 1_600_000_000


@pytest.mark.parametrize("stamp", [
    {"sec": 5, "nanosec": 7}, {"secs": 5, "nsecs": 7}, {"sec": 5, "nsec": 7},  # ROS 2, 1, Foxglove
    {"secs": 5, "nanosec": 7}, {"sec": 5, "nsecs": 7}, {"secs": 5, "nsec": 7},  # rosbridge mixes
])
def test_every_time_spelling_rosbridge_suite_and_foxglove_write_is_accepted(
        stamp: dict[str, int]) -> None:
    header = check_message("std_msgs/msg/Header", {"stamp": stamp, "frame_id": "base_link"})
    assert header["stamp"] == {"sec": 5, "nanosec": 7}
    duration = check_message("builtin_interfaces/msg/Duration", stamp)
    assert duration == {"sec": 5, "nanosec": 7}
    assert check_message("builtin_interfaces/msg/Time", {"sec": 5}) == {"sec": 5, "nanosec": 0}


def test_uint8_arrays_are_base64_both_ways() -> None:
    from_list = check_message("std_msgs/msg/UInt8MultiArray", {"data": [1, 2, 3]})
    from_b64 = check_message("std_msgs/msg/UInt8MultiArray", {"data": "AQID"})
    assert from_list["data"] == from_b64["data"] == b"\x01\x02\x03"
    assert json.loads(encode(from_list))["data"] == "AQID"


def test_non_finite_floats_encode_as_null_never_nan() -> None:
    text = encode({"a": math.nan, "b": [1.0, math.inf, -math.inf], "c": np.array([np.nan, 2.0])})
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"a": None, "b": [1.0, None, None], "c": [None, 2.0]}


def test_scan_conversion_checks_against_laserscan_and_sends_null() -> None:
    msg = scan_msg(FakeScan())
    check_message("sensor_msgs/msg/LaserScan", json.loads(encode(msg)))
    decoded = json.loads(encode(msg))
    assert decoded["ranges"] == [1.25, None, None, pytest.approx(0.98)]
    assert decoded["header"] == {"stamp": {"sec": 1700000000, "nanosec": 250000000},
                                 "frame_id": "laser"}


def test_odometry_conversion_checks_against_its_definition() -> None:
    sample = OdomSample(1.5, "odom", "base_link", 1.0, 2.0, math.pi / 2, 0.1, 0.2,
                        [0.1] * 6, [0.2] * 6)
    msg = check_message("nav_msgs/msg/Odometry", json.loads(encode(odometry_msg(sample))))
    assert msg["pose"]["pose"]["orientation"]["z"] == pytest.approx(math.sqrt(0.5))
    assert msg["pose"]["covariance"][7] == 0.1 and msg["twist"]["covariance"][35] == 0.2


def test_typedefs_full_text_has_gendeps_sections() -> None:
    text = full_text("nav_msgs/msg/Odometry")
    assert text.startswith("# Pose in header.frame_id")
    sections = text.split("\n" + "=" * 80 + "\n")
    names = [s.splitlines()[0] for s in sections[1:]]
    assert names[0] == "MSG: std_msgs/Header"
    for expected in ("MSG: builtin_interfaces/Time", "MSG: geometry_msgs/PoseWithCovariance",
                     "MSG: geometry_msgs/Quaternion", "MSG: geometry_msgs/TwistWithCovariance"):
        assert expected in names
    assert len(names) == len(set(names))
    assert "float64 w 1" in text
    log_text = full_text("rcl_interfaces/msg/Log")
    assert "byte ERROR=40" in log_text and "MSG: builtin_interfaces/Time" in log_text


@pytest.mark.parametrize(("text", "fragment", "rid"), [
    ("{not json", "invalid JSON", None),
    ("[1, 2]", "must be a JSON object", None),
    ('{"id": "x"}', "missing field 'op'", "x"),
    ('{"op": 3, "id": 4}', "field 'op': expected a string", 4),
    ('{"op": "publish", "x": NaN}', "invalid JSON", None),
    ('{"op": "publish", "id": [1]}', "field 'id'", None),
])
def test_frame_errors(text: str, fragment: str, rid: object) -> None:
    with pytest.raises(ProtocolError) as info:
        decode_frame(text)
    assert fragment in info.value.message
    try:  # the id the session answers with: the parsed frame's, when it has a valid one
        parsed = json.loads(text)
    except ValueError:
        parsed = None
    assert request_id(parsed) == rid


def test_topic_names_are_canonical_with_the_spelling_kept() -> None:
    assert topic_name({"op": "subscribe", "topic": "odom"}) == ("/odom", "odom")
    with pytest.raises(ProtocolError):
        topic_name({"op": "subscribe", "topic": "/a//b"})
    with pytest.raises(ProtocolError):
        topic_name({"op": "subscribe", "topic": 5})


def test_names_seen_before_are_answered_alike_and_the_memory_of_them_is_bounded() -> None:
    for _ in range(3):  # the first time checked, then remembered: the same answers
        assert topic_name({"op": "publish", "topic": "cmd_vel"}) == ("/cmd_vel", "cmd_vel")
        with pytest.raises(ProtocolError, match="not a valid ROS name"):
            topic_name({"op": "publish", "topic": "/a b"})
        with pytest.raises(ProtocolError, match="missing field 'topic'"):
            topic_name({"op": "publish", "service": "cmd_vel"})
    for i in range(3 * codec.VALID_NAMES_KEPT):
        topic_name({"op": "subscribe", "topic": f"/t{i}"})
    assert len(codec._VALID_NAMES) <= codec.VALID_NAMES_KEPT
    assert publish_frame("/t1", "{}") == '{"op":"publish","topic":"/t1","msg":{}}'


def test_fragments_round_trip_in_any_order() -> None:
    text = encode({"op": "publish", "topic": "/x", "msg": {"data": "y" * 1000}})
    pieces = [json.loads(p) for p in fragments(text, 97, "f1")]
    assert len(pieces) == math.ceil(len(text) / 97)
    joiner = Defragmenter(FragmentLimits(max_message_bytes=20_000))
    results = [joiner.add(p, now=0.0) for p in reversed(pieces)]
    assert results[:-1] == [None] * (len(pieces) - 1)
    assert results[-1] == text and joiner.pending == 0


def test_defragmenter_bounds() -> None:
    joiner = Defragmenter(FragmentLimits(max_message_bytes=200, max_sets=1, timeout_s=5.0))
    with pytest.raises(ProtocolError, match=r"the limit is 200 \(\[rosbridge\] max_message_b"):
        joiner.add({"op": "fragment", "id": "a", "data": "x" * 137, "num": 0, "total": 2},
                   now=0.0)
    joiner.add({"op": "fragment", "id": "b", "data": "x", "num": 0, "total": 2}, now=0.0)
    with pytest.raises(ProtocolError, match="in flight"):
        joiner.add({"op": "fragment", "id": "c", "data": "x", "num": 0, "total": 2}, now=1.0)
    joiner.add({"op": "fragment", "id": "c", "data": "x", "num": 0, "total": 2}, now=10.0)
    assert joiner.pending == 1  # "b" expired
    with pytest.raises(ProtocolError, match="0 <= num < total"):
        joiner.add({"op": "fragment", "id": "d", "data": "x", "num": 2, "total": 2}, now=10.0)


def test_defragmenter_counts_utf8_bytes_and_empty_fragments() -> None:
    joiner = Defragmenter(FragmentLimits(max_message_bytes=10_000, max_bytes=10_000))
    joiner.add({"op": "fragment", "id": "e", "data": "😀" * 100, "num": 0, "total": 3},
               now=0.0)
    assert joiner.held_bytes == 400 + FRAGMENT_COST
    joiner.add({"op": "fragment", "id": "e", "data": "", "num": 1, "total": 3}, now=0.0)
    assert joiner.held_bytes == 400 + 2 * FRAGMENT_COST
    assert joiner.add({"op": "fragment", "id": "e", "data": "", "num": 2, "total": 3},
                      now=0.0) == "😀" * 100
    assert joiner.held_bytes == 0
    with pytest.raises(ProtocolError, match="max_fragments_per_message"):
        joiner.add({"op": "fragment", "id": "f", "data": "", "num": 0, "total": 10**9},
                   now=0.0)


def _messages(n: int) -> list[SharedMessage]:
    return [SharedMessage("/t", {"data": str(i)}) for i in range(n)]


def test_throttle_without_queue_drops_inside_the_window() -> None:
    queue = TopicQueue("/t", "/t", state=True)
    queue.set_entry("s", SubscribeOptions(throttle_s=0.1))
    accepted = [queue.offer(m, now=i * 0.03) for i, m in enumerate(_messages(10))]
    # accepted at t = 0, 0.12, 0.24 (each 0.1 s after the last accepted one)
    assert accepted == [True, False, False, False, True, False, False, False, True, False]
    assert queue.dropped == 7 + 2  # 7 inside the window, 2 replaced before being sent
    assert len(queue.queue) == 1


def test_queue_length_keeps_the_newest_and_paces_them() -> None:
    queue = TopicQueue("/t", "/t", state=True)
    queue.set_entry("s", SubscribeOptions(throttle_s=0.5, queue_length=3))
    for m in _messages(10):
        queue.offer(m, now=0.0)
    sent = []
    now = 0.0
    while True:
        message, wait = queue.take(now)
        if message is None and wait is None:
            break
        if message is None:
            assert wait is not None and wait > 0
            now += wait
            continue
        sent.append((now, message.msg_json()))
    assert [json.loads(text)["data"] for _, text in sent] == ["7", "8", "9"]
    assert [t for t, _ in sent] == [0.0, 0.5, 1.0]


def test_subscriptions_merge_to_the_minimum_and_unmerge() -> None:
    queue = TopicQueue("/t", "/t", state=False)
    queue.set_entry("a", SubscribeOptions(0.5, 10, 4000))
    queue.set_entry("b", SubscribeOptions(0.2, 5, None))
    assert queue.options == SubscribeOptions(0.2, 5, 4000)
    queue.remove_entry("b")
    assert queue.options == SubscribeOptions(0.5, 10, 4000)
    queue.set_entry("a", SubscribeOptions())
    assert queue.queue.maxlen == EVENT_QUEUE  # event topic: every message counts, bounded


def test_state_topic_keeps_only_the_latest() -> None:
    queue = TopicQueue("/odom", "/odom", state=True)
    queue.set_entry(None, SubscribeOptions())
    for m in _messages(5):
        queue.offer(m, now=0.0)
    assert len(queue.queue) == 1 and queue.dropped == 4
    message, _ = queue.take(0.0)
    assert message is not None and json.loads(message.msg_json()) == {"data": "4"}


def test_shared_message_is_encoded_once_per_spelling() -> None:
    calls = []

    def convert(source: object) -> dict[str, object]:
        calls.append(source)
        return {"data": "x"}

    shared = SharedMessage("/t", object(), convert)
    assert shared.frame("/t") == shared.frame("/t")
    assert json.loads(shared.frame("t")) == {"op": "publish", "topic": "t",
                                             "msg": {"data": "x"}}
    assert len(calls) == 1


# -- properties: merged options, fragments, budgets -------------------------------------------

OPTION_VALUES = st.builds(SubscribeOptions, st.sampled_from([0.0, 0.01, 0.1, 1.0]),
                          st.integers(0, 5), st.one_of(st.none(), st.integers(1, 9)))


@given(st.lists(st.tuples(st.booleans(), st.integers(0, 6), OPTION_VALUES), max_size=60))
def test_merged_options_are_always_the_minimum_of_the_live_entries(
        steps: list[tuple[bool, int, SubscribeOptions]]) -> None:
    queue = TopicQueue("/t", "/t", state=True)
    live: dict[int, SubscribeOptions] = {}
    for add, key, options in steps:
        if add:
            queue.set_entry(key, options)
            live[key] = options
        elif key in live:
            queue.remove_entry(key)
            del live[key]
        if live:
            sizes = [o.fragment_size for o in live.values() if o.fragment_size]
            assert queue.options == SubscribeOptions(
                min(o.throttle_s for o in live.values()),
                min(o.queue_length for o in live.values()), min(sizes) if sizes else None)


@settings(max_examples=50)
@given(st.text(min_size=1, max_size=400), st.integers(1, 50), st.randoms())
def test_any_text_survives_fragments_in_any_order(text: str, size: int,
                                                  rng: random.Random) -> None:
    pieces = [json.loads(p) for p in fragments(text, size, 7)]
    rng.shuffle(pieces)
    joiner = Defragmenter(FragmentLimits(max_message_bytes=10**6, max_bytes=10**6))
    results = [joiner.add(p, now=0.0) for p in pieces]
    assert results[-1] == text and results[:-1] == [None] * (len(pieces) - 1)
    assert joiner.held_bytes == 0 and joiner.pending == 0


@given(st.lists(st.tuples(st.integers(0, 3), st.integers(0, 5), st.text(max_size=30)),
                max_size=80))
def test_held_fragment_bytes_never_exceed_the_client_budget(
        steps: list[tuple[int, int, str]]) -> None:
    limits = FragmentLimits(max_message_bytes=400, max_sets=3, max_bytes=600)
    joiner = Defragmenter(limits)
    for rid, num, data in steps:
        with contextlib.suppress(ProtocolError):
            joiner.add({"op": "fragment", "id": rid, "data": data, "num": num, "total": 6},
                       now=0.0)
        assert 0 <= joiner.held_bytes <= limits.max_bytes
        assert joiner.pending <= limits.max_sets


def test_token_bucket_rate_burst_and_credit() -> None:
    now = [0.0]
    bucket = TokenBucket(rate=10.0, burst=3, clock=lambda: now[0])
    assert [bucket.take() for _ in range(4)] == [True, True, True, False]
    now[0] = 0.1
    assert bucket.take() and not bucket.take()
    assert bucket.reserve(5.0) == pytest.approx(0.5)  # on credit: paid for in 0.5 s
    now[0] = 10.0
    assert bucket.take(3.0)  # refills up to the burst, no further


def test_rate_limited_log_counts_what_it_leaves_out(caplog: pytest.LogCaptureFixture) -> None:
    now = [0.0]
    line = RateLimitedLog(logging.getLogger("arbiterd.test"), interval_s=10.0,
                          clock=lambda: now[0])
    with caplog.at_level(logging.INFO, "arbiterd.test"):
        for i in range(5):
            line(logging.INFO, f"bad {i}")
        now[0] = 11.0
        line(logging.INFO, "bad 5")
    assert [r.getMessage() for r in caplog.records] == [
        "bad 0", "bad 5 (4 more like it in the last 11 s)"]


def test_a_scan_is_the_same_json_text_through_the_fast_conversion() -> None:
    """The JSON path converts scans to numpy arrays for orjson; the text is scan_msg's."""
    ranges = np.array([1.23456, np.inf, 0.2, np.nan, 12.0], dtype=np.float32)
    scan = LaserScan(1700000000.25, "laser", -math.pi, math.pi, 2 * math.pi / 5, 0.0, 0.1,
                     0.15, 12.0, ranges, np.array([47.0, 0.0, 3.5, 1.0, 2.0], dtype=np.float32))
    assert SharedMessage("/scan", scan, scan_msg).msg_json() == encode(scan_msg(scan))
    assert '"ranges":[1.2346,null,0.2,null,12.0]' in SharedMessage("/scan", scan,
                                                                  scan_msg).msg_json()
