# The ROS 2 face's CDR and node announcement against rosbags, an independent implementation.
from __future__ import annotations

import contextlib
import random
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from daemon.components.ros2 import announce
from daemon.messages import cdr, cdr_read
from daemon.messages.cdr import CdrError
from daemon.messages.msgtypes import known_types

typesys = pytest.importorskip("rosbags.typesys", reason="rosbags is in the test extra")
STORES = {"jazzy": typesys.get_typestore(typesys.Stores.ROS2_JAZZY),
          "humble": typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)}
JAZZY = STORES["jazzy"]
#: the daemon's message types that ROS 2 defines too (arbiterd_msgs is its own)
SHARED = [name for name in known_types() if name in JAZZY.fielddefs]
NUMPY = {"bool": np.bool_, "int8": np.int8, "uint8": np.uint8, "char": np.uint8,
         "byte": np.uint8, "int16": np.int16, "uint16": np.uint16, "int32": np.int32,
         "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64,
         "float32": np.float32, "float64": np.float64}
DUMMY = "structure_needs_at_least_one_member"


def sample_value(node: tuple[Any, Any], rng: random.Random, store: Any) -> Any:
    """A random value of a rosbags field type (BASE, NAME, ARRAY, SEQUENCE)."""
    kind, detail = node
    if kind == typesys.base.Nodetype.BASE:
        return sample_scalar(detail[0], rng)
    if kind == typesys.base.Nodetype.NAME:
        return sample_message(detail, rng, store)
    element, size = detail
    count = size if kind == typesys.base.Nodetype.ARRAY else rng.randrange(4)
    if element[0] == typesys.base.Nodetype.BASE and element[1][0] in NUMPY:
        base = element[1][0]
        return np.array([sample_scalar(base, rng) for _ in range(count)], dtype=NUMPY[base])
    return [sample_value(element, rng, store) for _ in range(count)]


def sample_scalar(base: str, rng: random.Random) -> Any:
    if base == "string":
        return rng.choice(["", "map", "base_link", "é/ünï"])
    if base == "bool":
        return rng.random() < 0.5
    if base.startswith("float"):
        return float(np.float32(rng.uniform(-100, 100)))
    if base in ("char", "byte"):  # rosbags packs byte signed, ROS 2 as an octet: agree on 0..127
        return rng.randrange(128)
    bits = int(base.removeprefix("u").removeprefix("int"))
    low = 0 if base.startswith("u") else -(2 ** (bits - 1))
    return rng.randrange(low, low + 2 ** bits)


def sample_message(name: str, rng: random.Random, store: Any) -> Any:
    fields = store.fielddefs[name][1]
    values = {f: sample_value(node, rng, store) for f, node in fields}
    if DUMMY in values:  # an empty struct: rosbags' dummy member, one zero byte on the wire
        values[DUMMY] = 0
    return store.types[name](**values)


def plain(value: Any) -> Any:
    """A rosbags message or our decoded dict as nested plain Python values."""
    if hasattr(value, "__dataclass_fields__"):
        return {f: plain(getattr(value, f)) for f in value.__dataclass_fields__
                if f not in ("__msgtype__", DUMMY) and not f.isupper()}  # not the constants
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (bytes, np.ndarray, list, tuple)):
        return [plain(v) for v in list(value)]
    if isinstance(value, (np.generic,)):
        return value.item()
    return value


@pytest.mark.parametrize("type_name", SHARED)
def test_each_shared_type_reads_and_writes_what_rosbags_writes(type_name: str) -> None:
    rng = random.Random(type_name)
    for _ in range(5):
        msg = sample_message(type_name, rng, JAZZY)
        theirs = bytes(JAZZY.serialize_cdr(msg, type_name))
        ours = cdr_read.decode(type_name, theirs)
        assert plain(ours) == plain(msg)
        assert cdr.encode(type_name, ours) == theirs


@pytest.mark.parametrize("type_name", ["sensor_msgs/msg/LaserScan", "nav_msgs/msg/Odometry",
                                       "tf2_msgs/msg/TFMessage", "geometry_msgs/msg/Twist"])
def test_every_truncation_is_a_cdr_error_naming_a_field(type_name: str) -> None:
    msg = sample_message(type_name, random.Random(7), JAZZY)
    whole = bytes(JAZZY.serialize_cdr(msg, type_name))
    for cut in range(len(whole)):
        try:
            cdr_read.decode(type_name, whole[:cut])
        except CdrError as exc:
            assert type_name in str(exc) or "msg" in str(exc) or cut < 4, str(exc)
        else:  # only the trailing alignment padding may go
            assert whole[cut:] == bytes(len(whole) - cut)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200), st.sampled_from(SHARED))
def test_arbitrary_bytes_decode_or_raise_cdr_error(data: bytes, type_name: str) -> None:
    with contextlib.suppress(CdrError):
        cdr_read.decode(type_name, b"\x00\x01\x00\x00" + data)


@pytest.mark.parametrize("distro", ["jazzy", "humble"])
def test_the_node_announcement_is_rmw_dds_commons_participant_entities_info(distro: str) -> None:
    store, size = STORES[distro], announce.GID_SIZE[distro]
    guid = bytes(range(16))
    node = announce.NodeInfo("/", "arbiterd", readers=[bytes([1]) * 16],
                             writers=[bytes([2]) * 16, bytes([3]) * 16])
    ours = announce.encode(guid, [node], size)
    name = "rmw_dds_common/msg/"
    gid = store.types[f"{name}Gid"]

    def as_gid(raw: bytes) -> Any:
        return gid(data=np.frombuffer(announce.gid(raw, size), dtype=np.uint8))

    theirs = store.serialize_cdr(store.types[f"{name}ParticipantEntitiesInfo"](
        gid=as_gid(guid), node_entities_info_seq=[store.types[f"{name}NodeEntitiesInfo"](
            node_namespace="/", node_name="arbiterd",
            reader_gid_seq=[as_gid(r) for r in node.readers],
            writer_gid_seq=[as_gid(w) for w in node.writers])]),
        f"{name}ParticipantEntitiesInfo")
    assert ours == bytes(theirs)
    participant, nodes = announce.decode(ours, size)
    assert participant == guid and nodes == [node]


def test_an_announcement_of_another_gid_size_is_refused() -> None:
    sample = announce.encode(bytes(16), [announce.NodeInfo("/", "n", [bytes(16)])], 24)
    with pytest.raises(CdrError):
        announce.decode(sample, 16)
