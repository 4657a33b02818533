# Every outgoing topic, fed a real payload of a simulated daemon with everything on, converts to
# exactly its ROS type: the CDR encoders (the flight recorder, rosbridge's cbor-raw, the ROS 2
# face) need every field, and a converter that fills only some passes rosbridge's JSON silently.
from __future__ import annotations

import asyncio
import json
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import pytest

from daemon.components.rosbridge.codec import encode as json_encode
from daemon.messages import cdr, cdr_read, scans
from daemon.messages.convert import JSON_CONVERT, JSON_TEXT
from daemon.messages.definitions import POSE_STAMPED, STRING
from daemon.messages.strict import check_fields, encode_strict
from daemon.topics import TopicOut
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rosbridge import connect
from tests.support.topic_samples import BusSamples, everything

#: how long the daemon may take to publish on every topic once driven (the first map, a plan)
CAPTURE_WITHIN_S = 30.0


@dataclass(frozen=True)
class Captured:
    """The running daemon's outgoing topics (its topic table: what each built component's
    ``topics()`` declared), who owns each, and a real bus payload per bus key."""

    topics: list[TopicOut[Any]]
    owners: dict[str, str]
    samples: dict[str, Any]

    def sample(self, topic: TopicOut[Any]) -> Any:
        return self.samples.get(topic.bus.name)


@pytest.fixture(scope="module")
def captured(tmp_path_factory: pytest.TempPathFactory) -> Captured:
    async def capture() -> Captured:
        workdir = tmp_path_factory.mktemp("samples")
        async with in_process_daemon(workdir, everything(workdir / "data")) as robot:
            table = robot.ctx.topics
            topics = table.outgoing()
            samples = BusSamples(robot.ctx.bus, [t.bus for t in topics])
            try:
                await drive(robot, samples)
            finally:
                samples.close()
            return Captured(topics, {t.name: table.owner(t.name) for t in topics},
                            dict(samples.samples))

    return asyncio.run(capture())


async def drive(robot: InProcessDaemon, samples: BusSamples) -> None:
    """What the robot publishes only when asked, asked for over rosbridge: a stamped command
    (/commands, /latency_reports) and a goal (/plan; its INFO log line goes to /rosout, at
    the level ``arbiterd run`` logs at); then wait, connected (a client that goes away brakes
    the robot), until every key has a sample."""
    logger = logging.getLogger()
    level = logger.level
    logger.setLevel(logging.INFO)
    try:
        await _drive(robot, samples)
    finally:
        logger.setLevel(level)


async def _drive(robot: InProcessDaemon, samples: BusSamples) -> None:
    async with connect(robot.ws_url) as client:
        await client.send(op="advertise", topic="/stamped_cmd_vel", type=STRING)
        await client.send(op="publish", topic="/stamped_cmd_vel", msg={"data": json.dumps(
            {"linear": {"x": 0.05}, "angular": {"z": 0.0}, "id": "sample"})})
        await client.send(op="advertise", topic="/goal_pose", type=POSE_STAMPED)
        await client.send(op="publish", topic="/goal_pose", id="goal", msg={
            "header": {"frame_id": "odom"},
            "pose": {"position": {"x": 0.5, "y": 0.0, "z": 0.0},
                     "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(0.25),
                                     "w": math.cos(0.25)}}})
        await samples.wait(CAPTURE_WITHIN_S)


def test_every_outgoing_topic_has_a_real_sample(captured: Captured) -> None:
    without = [f"{t.name} ({captured.owners[t.name]}, bus key {t.bus.name!r}, {t.rate})"
               for t in captured.topics if captured.sample(t) is None]
    covered = len(captured.topics) - len(without)
    print(f"\n{covered} of {len(captured.topics)} outgoing topics have a real sample")
    assert captured.topics, "the daemon declared no outgoing topic"
    assert not without, (
        f"no payload within {CAPTURE_WITHIN_S} s on {len(without)} topics; make the test "
        f"drive the robot so that they publish (drive() in tests/test_topic_messages.py): "
        + "; ".join(without))


def test_each_topics_converter_gives_exactly_its_message_type(captured: Captured) -> None:
    """The topic's converter on a real payload has every field of the type and nothing else,
    at every depth, each scalar of its kind, and encodes as CDR that decodes to the same."""
    failures = {}
    for topic in captured.topics:
        payload = captured.sample(topic)
        if payload is not None:
            problems = _problems(topic.type, topic.convert, payload)
            if problems:
                failures[topic.name] = problems
    assert not failures, "converters that do not fill their message type (the recorder, "\
        "cbor-raw and the ROS 2 face drop every such message):\n" + "\n".join(
            f"  {name} ({captured.owners[name]}): " + "; ".join(problems)
            for name, problems in failures.items())


def test_the_binary_and_json_variants_of_a_conversion_agree_with_it(captured: Captured) -> None:
    """Where a transport converts a type its own way (scans as float32 arrays and their own CDR
    encoder; JSON straight from numpy or to text), that way gives the same message."""
    failures, checked = [], 0
    for topic in captured.topics:
        payload = captured.sample(topic)
        if payload is None:
            continue
        binary = scans.BINARY_CONVERT.get(topic.type)
        if binary is not None:
            checked += 1
            failures += [f"{topic.name} (binary): {p}"
                         for p in _problems(topic.type, binary, payload)]
            direct = scans.BINARY_CDR.get(topic.type)
            if direct is not None and direct(payload) != cdr.encode(topic.type,
                                                                      binary(payload)):
                failures.append(f"{topic.name}: its own CDR encoder differs from the generic "
                                f"one")
        plain = json.loads(json_encode(topic.convert(payload)))
        twin = JSON_CONVERT.get(topic.convert)
        if twin is not None:
            checked += 1
            if json.loads(json_encode(twin(payload))) != plain:
                failures.append(f"{topic.name}: the JSON-only conversion differs")
        text = JSON_TEXT.get(topic.convert)
        if text is not None:
            checked += 1
            if json.loads(text(payload)) != plain:
                failures.append(f"{topic.name}: the JSON text conversion differs")
    assert checked, "no topic with a conversion of a transport's own was sampled"
    assert not failures, "\n".join(failures)


def _problems(type_name: str, convert: Callable[[Any], Any], payload: Any) -> list[str]:
    try:
        msg = convert(payload)
    except Exception as exc:
        return [f"the converter raised {exc!r}"]
    check = check_fields(type_name, msg)
    problems = list(check.problems)
    problems += [f"{path}: empty in the sample, so its items' fields were not checked (capture "
                 f"one with items)" for path in sorted(check.unchecked)]
    if problems:
        return problems
    try:
        data = cdr.encode(type_name, msg)
        again = cdr.encode(type_name, cdr_read.decode(type_name, data))
    except (cdr.CdrError, ValueError, TypeError, AttributeError) as exc:
        return [f"CDR: {exc}"]
    return [] if again == data else ["CDR: decoding and encoding again changes the bytes"]


# -- the strict check itself -----------------------------------------------------------------


def _pose_stamped(**header: Any) -> dict[str, Any]:
    return {"header": header,
            "pose": {"position": {"x": 1.0, "y": 2.0, "z": 0.0},
                     "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}


def test_the_strict_check_names_missing_and_unknown_fields_by_path() -> None:
    stamp = {"sec": 1, "nanosec": 2}
    assert check_fields(POSE_STAMPED, _pose_stamped(stamp=stamp, frame_id="odom")).ok
    check = check_fields(POSE_STAMPED, _pose_stamped(stamp={"sec": 1}, frameid="odom"))
    assert check.problems == ["msg.header.frameid: not a field of std_msgs/msg/Header",
                              "msg.header.stamp.nanosec: missing (uint32)",
                              "msg.header.frame_id: missing (string)"]
    with pytest.raises(cdr.CdrError, match=r"msg\.header\.frame_id: missing"):
        encode_strict(POSE_STAMPED, _pose_stamped(stamp=stamp))
    assert encode_strict(POSE_STAMPED, _pose_stamped(stamp=stamp, frame_id="odom")) == \
        cdr.encode(POSE_STAMPED, _pose_stamped(stamp=stamp, frame_id="odom"))


def test_the_strict_check_refuses_what_the_encoder_would_coerce() -> None:
    check = check_fields("std_msgs/msg/Bool", {"data": 1})
    assert check.problems == ["msg.data: expected bool, got int 1"]
    check = check_fields("diagnostic_msgs/msg/DiagnosticArray", {
        "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""},
        "status": [{"level": 0, "name": None, "message": "", "hardware_id": "", "values": []}]})
    assert check.problems == ["msg.status[0].name: expected string, got NoneType None"]
    assert check.unchecked == {"msg.status[].values[]"}


def test_an_empty_sequence_leaves_its_items_unchecked_until_one_has_items() -> None:
    header = {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}
    status = {"level": 0, "name": "a", "message": "", "hardware_id": "", "values": []}
    with_values = {**status, "values": [{"key": "k", "value": "v"}]}
    check = check_fields("diagnostic_msgs/msg/DiagnosticArray",
                         {"header": header, "status": [status, with_values]})
    assert check.ok and not check.unchecked
    unnamed = {key: value for key, value in status.items() if key != "name"}
    check = check_fields("diagnostic_msgs/msg/DiagnosticArray",
                         {"header": header, "status": [unnamed, unnamed, unnamed]})
    assert check.problems == ["msg.status[0].name: missing (string) (and in 2 more items)"]
    assert check_fields("tf2_msgs/msg/TFMessage", {"transforms": []}).unchecked == {
        "msg.transforms[]"}
