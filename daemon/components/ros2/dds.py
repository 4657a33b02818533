# The Cyclone DDS side of the ROS 2 face: participant, typed endpoints, raw CDR in and out.
from __future__ import annotations

import ctypes
import importlib
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from types import ModuleType
from typing import Any

from daemon.components.ros2 import announce
from daemon.components.ros2.names import cyclone_config, dds_type
from daemon.messages.msgtypes import get_type

PACKAGE = "cyclonedds"
INSTALL_HINT = ("install the ros2 extra: on Debian / Raspberry Pi OS `apt install "
                "cyclonedds-dev`, then `pip install cyclonedds==0.10.2` into arbiterd's venv "
                "with CYCLONEDDS_HOME set as docs/ros2.md shows")
#: how long a reliable write may wait for room in the writer's history (the writer thread's)
MAX_BLOCKING_MS = 20

# ROS primitive -> its type in cyclonedds.idl.types (the binding has no octet: byte is uint8)
_IDL_PRIMITIVES: dict[str, str] = {
    "int8": "int8", "uint8": "uint8", "char": "uint8", "byte": "uint8", "int16": "int16",
    "uint16": "uint16", "int32": "int32", "uint32": "uint32", "int64": "int64",
    "uint64": "uint64", "float32": "float32", "float64": "float64",
}


class DdsError(OSError):
    """Cyclone DDS refused to make the participant (its configuration, security's files)."""


class DdsUnavailable(RuntimeError):
    """The cyclonedds binding cannot be imported."""


@cache
def cyclone() -> dict[str, ModuleType]:
    """The binding's modules, imported on first use (a robot without the extra never does)."""
    try:
        return {name: importlib.import_module(f"{PACKAGE}.{name}")
                for name in ("domain", "pub", "sub", "topic", "core", "qos", "idl",
                             "idl.types", "builtin", "util", "internal", "_clayer")}
    except ImportError as exc:
        raise DdsUnavailable(f"the Python package {PACKAGE} is not installed ({exc}); "
                             f"{INSTALL_HINT}") from None


def available() -> str | None:
    """None when the binding imports, else why not and how to install it."""
    try:
        cyclone()
    except DdsUnavailable as exc:
        return str(exc)
    return None


def libddsc_path() -> Path | None:
    """The Cyclone DDS C library the binding loaded (its security plugins sit beside it)."""
    cyclone()["internal"].load_cyclonedds()
    try:
        maps = Path("/proc/self/maps").read_text().split()
    except OSError:
        return None
    return next((Path(word) for word in maps if "/libddsc.so" in word), None)


# -- types ----------------------------------------------------------------------------------


@cache
def idl_type(ros_type: str) -> Any:
    """A binding struct class for ``pkg/msg/Type`` built from the message layer's definition
    (its name ``pkg::msg::dds_::Type_``; nested types too)."""
    mods = cyclone()
    fields = {f.name: _idl_field(f.base, f.is_array, f.length)
              for f in get_type(ros_type).fields}
    if not fields:  # as rosidl does for an empty message
        fields = {"structure_needs_at_least_one_member": mods["idl.types"].uint8}
    name = dds_type(ros_type)
    return mods["idl"].make_idl_struct(name.split("::")[-1], name.replace("::", "."), fields)


def _idl_field(base: str, is_array: bool, length: int | None) -> Any:
    types = cyclone()["idl.types"]
    if base in _IDL_PRIMITIVES:
        element: Any = getattr(types, _IDL_PRIMITIVES[base])
    elif base == "bool":
        element = bool
    elif base == "string":
        element = str
    else:
        element = idl_type(base)
    if not is_array:
        return element
    return types.array[element, length] if length is not None else types.sequence[element]


@cache
def announcement_type(gid_size: int) -> Any:
    """rmw_dds_common's ParticipantEntitiesInfo with a Gid of ``gid_size`` bytes."""
    mods = cyclone()
    types, idl = mods["idl.types"], mods["idl"]
    octet = types.uint8 if gid_size == 16 else types.char
    gid_t = idl.make_idl_struct("Gid_", "rmw_dds_common.msg.dds_.Gid_",
                                {"data": types.array[octet, gid_size]})
    node_t = idl.make_idl_struct(
        "NodeEntitiesInfo_", "rmw_dds_common.msg.dds_.NodeEntitiesInfo_",
        {"node_namespace": str, "node_name": str, "reader_gid_seq": types.sequence[gid_t],
         "writer_gid_seq": types.sequence[gid_t]})
    return idl.make_idl_struct(
        "ParticipantEntitiesInfo_", announce.TYPE.replace("::", "."),
        {"gid": gid_t, "node_entities_info_seq": types.sequence[node_t]})


def _without_type_information(data_type: Any) -> None:
    """Make the binding announce no XTypes information for ``data_type`` (Kilted's Fast DDS
    then matches by name; with it, sequences do not match)."""
    data_type.__idl__.populate()
    data_type.__idl__.fill_type_data = lambda: None


# -- QoS ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class QosSpec:
    """What ROS 2 says about a topic's QoS: reliable or best effort, transient local or
    volatile, keep last ``depth``."""

    reliable: bool
    transient_local: bool
    depth: int

    def qos(self, user_data: bytes = b"") -> Any:
        """The binding's QoS; ``user_data`` is the endpoints' USER_DATA (ROS 2's type hash)."""
        mods = cyclone()
        policy, duration = mods["qos"].Policy, mods["util"].duration
        reliability = (policy.Reliability.Reliable(duration(milliseconds=MAX_BLOCKING_MS))
                       if self.reliable else policy.Reliability.BestEffort)
        durability = (policy.Durability.TransientLocal if self.transient_local
                      else policy.Durability.Volatile)
        policies = [reliability, durability, policy.History.KeepLast(self.depth)]
        if user_data:
            policies.append(policy.Userdata(user_data))
        return mods["qos"].Qos(*policies)


ANNOUNCE_QOS = QosSpec(reliable=True, transient_local=True, depth=1)


class _MatchedCounts:
    """``dds_get_{publication,subscription}_matched_status`` (the binding has no call for
    them), through its own handle on the C library."""

    def __init__(self, internal: ModuleType) -> None:
        lib = internal.load_cyclonedds()
        types = internal.dds_c_t
        self._pub_status, self._sub_status = (types.publication_matched_status,
                                              types.subscription_matched_status)
        self._pub = lib.dds_get_publication_matched_status
        self._pub.argtypes = [ctypes.c_int32, ctypes.POINTER(self._pub_status)]
        self._sub = lib.dds_get_subscription_matched_status
        self._sub.argtypes = [ctypes.c_int32, ctypes.POINTER(self._sub_status)]
        self._pub.restype = self._sub.restype = ctypes.c_int32

    def publication(self, ref: int) -> int:
        status = self._pub_status()
        return int(status.current_count) if self._pub(ref, ctypes.byref(status)) >= 0 else 0

    def subscription(self, ref: int) -> int:
        status = self._sub_status()
        return int(status.current_count) if self._sub(ref, ctypes.byref(status)) >= 0 else 0


# -- the participant ----------------------------------------------------------------------

#: every sample state, view state and instance state: a reader's condition for "has samples"
ANY_SAMPLE = 0x7F
#: the status that wakes a reader's watcher when a publisher of its topic comes or goes
SUBSCRIPTION_MATCHED = 1 << 12


class DdsNode:
    """One DDS participant in ``domain`` with its endpoints. Writes take serialised CDR;
    readers are taken from by the caller. No endpoint has a Python listener: a DDS thread in
    a listener waits for the GIL while holding the entity, and a writer thread that holds the
    GIL while it writes to a local reader of that entity then waits for it (a deadlock; see
    docs/ros2.md). Matches are counted on request, samples waited for on a :meth:`waitset`."""

    def __init__(self, domain: int, localhost: bool, type_information: bool,
                 security: str = "") -> None:
        mods = self.mods = cyclone()
        self.type_information = type_information
        self.domain = mods["domain"].Domain(domain, cyclone_config(localhost, security))
        try:
            self.participant = mods["domain"].DomainParticipant(domain)
        except mods["core"].DDSException as exc:
            self.domain.__del__()
            raise DdsError(str(exc)) from None
        self.publisher = mods["pub"].Publisher(self.participant)
        self.subscriber = mods["sub"].Subscriber(self.participant)
        self._topics: dict[str, Any] = {}
        self._entities: list[Any] = []
        self._matched = _MatchedCounts(mods["internal"])

    @property
    def guid(self) -> bytes:
        return bytes(self.participant.guid.bytes)

    @staticmethod
    def guid_of(entity: Any) -> bytes:
        return bytes(entity.guid.bytes)

    def _topic(self, name: str, data_type: Any) -> Any:
        if name not in self._topics:
            if not self.type_information:
                _without_type_information(data_type)
            self._topics[name] = self.mods["topic"].Topic(self.participant, name, data_type)
        return self._topics[name]

    def writer(self, name: str, data_type: Any, qos: QosSpec, user_data: bytes = b"") -> Any:
        writer = self.mods["pub"].DataWriter(self.publisher, self._topic(name, data_type),
                                             qos.qos(user_data))
        self._entities.append(writer)
        return writer

    def reader(self, name: str, data_type: Any, qos: QosSpec, user_data: bytes = b"") -> Any:
        reader = self.mods["sub"].DataReader(self.subscriber, self._topic(name, data_type),
                                             qos.qos(user_data))
        self._entities.append(reader)
        return reader

    def publication_matches(self, writer: Any) -> int:
        """How many readers match ``writer`` now."""
        return self._matched.publication(writer._ref)

    def subscription_matches(self, reader: Any) -> int:
        """How many writers match ``reader`` now (resets its matched status)."""
        return self._matched.subscription(reader._ref)

    def waitset(self, readers: list[Any], matches: list[Any]) -> Any:
        """A waitset that triggers while one of ``readers`` holds samples, or when the
        writers matching one of ``matches`` change."""
        core = self.mods["core"]
        waitset = core.WaitSet(self.participant)
        for reader in readers:
            condition = core.ReadCondition(reader, ANY_SAMPLE)
            self._entities.append(condition)
            waitset.attach(condition)
        for reader in matches:
            reader.set_status_mask(SUBSCRIPTION_MATCHED)
            waitset.attach(reader)
        self._entities.append(waitset)
        return waitset

    @staticmethod
    def wait(waitset: Any, seconds: float) -> int:
        """Block (without the GIL) until the waitset triggers or ``seconds`` pass."""
        return int(waitset.wait(int(seconds * 1e9)))

    def publications_reader(self) -> Any:
        """A reader of the DCPSPublication built-in topic: every writer discovered."""
        builtin = self.mods["builtin"]
        reader = builtin.BuiltinDataReader(self.participant,
                                           builtin.BuiltinTopicDcpsPublication)
        self._entities.append(reader)
        return reader

    def write(self, writer: Any, data: bytes) -> None:
        """Write one serialised sample (encapsulation header included)."""
        pad = -len(data) % 4
        ret = self.mods["_clayer"].ddspy_write(writer._ref, data + bytes(pad) if pad else data)
        if ret < 0:
            raise OSError(f"DDS write failed ({ret})")

    def take_raw(self, reader: Any, n: int = 32) -> list[tuple[bytes, Any]]:
        """Up to ``n`` samples as (serialised bytes, sample info), valid data only."""
        ret = self.mods["_clayer"].ddspy_take(reader._ref, n)
        if isinstance(ret, int):
            return []
        return [(bytes(data), info) for data, info in ret if info.valid_data]

    def close(self) -> None:
        """Delete every entity, then the participant and the domain (peers see it leave)."""
        for entity in (*reversed(self._entities), *self._topics.values(), self.publisher,
                       self.subscriber, self.participant, self.domain):
            entity.__del__()
        self._entities.clear()
        self._topics.clear()
