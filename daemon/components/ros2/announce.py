# The node announcement on ros_discovery_info (rmw_dds_common ParticipantEntitiesInfo) as CDR.
from __future__ import annotations

import struct
from dataclasses import dataclass, field

from daemon.messages.cdr import ENCAPSULATION, CdrError
from daemon.messages.cdr_read import CdrReader

#: the Gid's size per ROS 2 release: a GUID padded to 24 bytes on Humble, the GUID on later ones
GID_SIZE = {"humble": 24, "jazzy": 16, "kilted": 16}
TOPIC = "ros_discovery_info"
TYPE = "rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"
U32 = struct.Struct("<I")


@dataclass
class NodeInfo:
    """One node of a participant: its namespace and name, its readers' and writers' GUIDs."""

    namespace: str
    name: str
    readers: list[bytes] = field(default_factory=list)
    writers: list[bytes] = field(default_factory=list)


def gid(guid: bytes, size: int) -> bytes:
    return guid.ljust(size, b"\0")[:size]


def encode(participant: bytes, nodes: list[NodeInfo], gid_size: int) -> bytes:
    """A ParticipantEntitiesInfo sample: ``participant``'s GUID and its nodes."""
    buf = bytearray(ENCAPSULATION)
    buf += gid(participant, gid_size)
    _count(buf, len(nodes))
    for node in nodes:
        _string(buf, node.namespace)
        _string(buf, node.name)
        for gids in (node.readers, node.writers):
            _count(buf, len(gids))
            for one in gids:
                buf += gid(one, gid_size)
    return bytes(buf)


def _pad(buf: bytearray) -> None:
    buf += bytes(-(len(buf) - len(ENCAPSULATION)) % 4)


def _count(buf: bytearray, n: int) -> None:
    _pad(buf)
    buf += U32.pack(n)


def _string(buf: bytearray, text: str) -> None:
    data = text.encode()
    _count(buf, len(data) + 1)
    buf += data + b"\0"


def decode(data: bytes, gid_size: int) -> tuple[bytes, list[NodeInfo]]:
    """The participant GUID and nodes of a sample; CdrError when it is not one."""
    if data[:2] != ENCAPSULATION[:2]:
        raise CdrError("ParticipantEntitiesInfo: not little-endian plain CDR")
    reader = CdrReader(data, "<")
    participant = reader.take(gid_size, "gid")[:16]
    nodes = []
    for i in range(reader.count("node_entities_info_seq")):
        path = f"node_entities_info_seq[{i}]"
        node = NodeInfo(reader.string(f"{path}.node_namespace"),
                        reader.string(f"{path}.node_name"))
        for gids in (node.readers, node.writers):
            for _ in range(reader.count(path)):
                gids.append(reader.take(gid_size, path)[:16])
        nodes.append(node)
    if reader.pos + 3 < len(data):  # more than the padding to 4 left: another layout
        raise CdrError("ParticipantEntitiesInfo: trailing bytes (another Gid size?)")
    return participant, nodes
