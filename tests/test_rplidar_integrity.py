# Stream integrity under junk bytes: what is published lies on the encoded range profile and
# every published revolution is (nearly) whole, in standard, express, dense and ultra streams.
from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensors.rplidar import records, synth
from sensors.rplidar.assembler import Revolution, RevolutionAssembler
from sensors.rplidar.device import LidarManager, ManagerConfig
from sensors.rplidar.requests import Ans, Descriptor, Health
from sensors.rplidar.streams import Discontinuity, Event, Samples, StreamParser
from sim.rplidar_emulator import A1, RplidarEmulator
from tests.support.wait import Collector, wait_for

ROOT = Path(__file__).resolve().parents[1]

F64 = npt.NDArray[np.float64]
ROTATION_HZ = 10.0
SEEDS = settings(max_examples=4, deadline=None, derandomize=True)


def profile_mm(angle_deg: F64) -> F64:
    """The world every stream here is encoded from: a range that varies fast with the angle
    (a sample put at a wrong angle, or given a wrong distance, is off it)."""
    a = np.deg2rad(angle_deg)
    result: F64 = 1500.0 + 800.0 * np.sin(5 * a) + 300.0 * np.cos(2 * a)
    return result


#: a capsule whose successor was lost is decoded with the advance before it: its angles may be
#: a q6 unit or two off the device's (0.03° is 2.5 mm on the steepest part of the profile)
ANGLE_TOLERANCE_DEG = 2 / 64


def on_profile(angle_deg: F64, distance_mm: F64, tolerance_mm: float) -> npt.NDArray[np.bool_]:
    """Samples within ``tolerance_mm`` of the profile somewhere within the angle tolerance."""
    near = np.stack([profile_mm(angle_deg + d)
                     for d in (-ANGLE_TOLERANCE_DEG, 0.0, ANGLE_TOLERANCE_DEG)])
    slack = tolerance_mm + 1e-6
    ok: npt.NDArray[np.bool_] = ((distance_mm >= near.min(axis=0) - slack)
                                 & (distance_mm <= near.max(axis=0) + slack))
    return ok


@dataclass(frozen=True)
class Kind:
    """One stream type as a device sends it at ``ROTATION_HZ``."""

    data_type: int
    us_per_sample: float
    records_per_junk: int  # junk arrives about every this many records
    tolerance_mm: float  # encoding quantum: distance error of an intact sample

    @property
    def size(self) -> int:
        return synth.STREAM_DESCRIPTORS[self.data_type].length

    @property
    def per_record(self) -> int:
        return synth.SAMPLES_PER_CAPSULE.get(self.data_type, 1)

    @property
    def step_deg(self) -> float:
        return self.us_per_sample * 1e-6 * ROTATION_HZ * 360.0

    @property
    def per_revolution(self) -> float:
        return 360.0 / self.step_deg


STANDARD = Kind(Ans.NODE, 508.0, 60, 0.125)  # A1 Standard
EXPRESS = Kind(Ans.CAPSULE, 254.0, 20, 0.5)  # A1 Express (legacy capsules)
DENSE = Kind(Ans.DENSE_CAPSULE, 31.25, 20, 0.5)  # S2 DenseBoost
ULTRA = Kind(Ans.ULTRA_CAPSULE, 127.0, 20, 10.0)  # A1 Boost; VBS majors round down


def rotor_q6(sample_index: npt.NDArray[np.int64], kind: Kind) -> npt.NDArray[np.int64]:
    return (np.rint(sample_index * kind.step_deg * 64).astype(np.int64)) % records.FULL_TURN_Q6


def node_stream(kind: Kind, turns: float) -> bytes:
    k = np.arange(int(turns * kind.per_revolution), dtype=np.int64)
    angle_q6 = rotor_q6(k, kind)
    start = angle_q6 < rotor_q6(k - 1, kind)
    dist = np.rint(profile_mm(angle_q6 / 64.0) * 4) / 4
    return synth.encode_nodes(angle_q6 / 64.0, dist, np.full(len(k), 15), start)


def _decoded(body: bytes, kind: Kind) -> records.DecodedSamples:
    decoders: dict[int, Callable[[records.U8, records.U8], records.DecodedSamples]] = {
        Ans.CAPSULE: records.decode_legacy, Ans.DENSE_CAPSULE: records.decode_dense,
        Ans.ULTRA_CAPSULE: records.decode_ultra}
    decode = decoders[kind.data_type]
    caps = np.frombuffer(body, dtype=np.uint8).reshape(-1, kind.size)
    return decode(caps[:-1], caps[1:])


def capsule_stream(kind: Kind, turns: float) -> bytes:
    """Capsules whose decoded samples (angles as the receiver computes them) lie on the profile;
    the last capsule only gives its predecessor a successor."""
    count = int(turns * kind.per_revolution / kind.per_record) + 1
    starts = rotor_q6(np.arange(count + 1, dtype=np.int64) * kind.per_record, kind)
    sync = np.arange(count + 1) == 0
    shape = (count + 1, kind.per_record)
    if kind.data_type == Ans.CAPSULE:
        dtheta = 48 + (np.arange(shape[0] * shape[1]).reshape(shape) // 8) % 16

        def encode(dist: F64) -> bytes:
            return synth.encode_legacy(starts, dist, dtheta, sync)
    elif kind.data_type == Ans.DENSE_CAPSULE:
        def encode(dist: F64) -> bytes:
            return synth.encode_dense(starts, dist, sync)
    else:
        def encode(dist: F64) -> bytes:
            return synth.encode_ultra(starts, dist, sync, next_first_mm=int(dist[-1, -1]))
    dist = np.full(shape, 1500.0)
    for _ in range(4):  # ultra angles depend on the distance: iterate to a fixed point
        angles = _decoded(encode(dist), kind).angle_deg
        dist[:-1] = profile_mm(angles).reshape(count, kind.per_record)
        dist[-1] = dist[-2]
    return encode(dist)[:count * kind.size]


def stream_of(kind: Kind, turns: float) -> bytes:
    body = node_stream(kind, turns) if kind.data_type == Ans.NODE else capsule_stream(kind, turns)
    return synth.STREAM_DESCRIPTORS[kind.data_type].encode() + body


def inject_junk(stream: bytes, kind: Kind, rng: np.random.Generator) -> tuple[bytes, int]:
    """1-8 random bytes at a random byte about every ``records_per_junk`` records."""
    every = kind.records_per_junk * kind.size
    out, last, events = [], 0, 0
    at = int(rng.integers(every // 2, every))
    while at < len(stream):
        out += [stream[last:at], rng.integers(0, 256, int(rng.integers(1, 9))).astype(
            np.uint8).tobytes()]
        last, events = at, events + 1
        at += int(rng.integers(3 * every // 4, 5 * every // 4))
    out.append(stream[last:])
    return b"".join(out), events


@dataclass
class Outcome:
    revolutions: list[Revolution]
    parser: StreamParser
    assembler: RevolutionAssembler
    junk_events: int

    def on_profile(self, kind: Kind) -> tuple[int, int]:
        """(published samples on the profile, published samples)."""
        angle = np.concatenate([r.angle_deg for r in self.revolutions])
        dist = np.concatenate([r.distance_mm for r in self.revolutions])
        ok = on_profile(angle, dist, kind.tolerance_mm)
        return int(ok.sum()), len(ok)

    def fill(self, kind: Kind) -> F64:
        """Samples of each published revolution over the samples a whole turn has."""
        return np.array([len(r) for r in self.revolutions]) / kind.per_revolution

    def summary(self, kind: Kind) -> str:
        good, total = self.on_profile(kind)
        fill = self.fill(kind)
        return (f"{len(self.revolutions)} revolutions, {total - good}/{total} samples off the "
                f"profile, fill {fill.min():.3f}..{fill.max():.3f}, "
                f"{self.junk_events} junk events")


def run(kind: Kind, turns: float, seed: int, junk: bool = True) -> Outcome:
    rng = np.random.default_rng(seed)
    stream, events = stream_of(kind, turns), 0
    if junk:
        stream, events = inject_junk(stream, kind, rng)
    parser = StreamParser()
    seconds_per_byte = kind.us_per_sample * 1e-6 * kind.per_record / kind.size
    assembler = RevolutionAssembler(sample_period=kind.us_per_sample * 1e-6)
    revolutions: list[Revolution] = []
    at = 0
    while at < len(stream):
        end = min(at + int(rng.integers(1, 600)), len(stream))
        revolutions += assembler.feed(parser.feed(stream[at:end]), end * seconds_per_byte)
        at = end
    return Outcome(revolutions, parser, assembler, events)


def check_integrity(outcome: Outcome, kind: Kind, turns: float, min_fill: float) -> None:
    good, total = outcome.on_profile(kind)
    summary = outcome.summary(kind)
    assert outcome.junk_events >= turns * kind.per_revolution / kind.per_record / (
        1.25 * kind.records_per_junk) - 1, summary
    # nothing is lost wholesale: most turns come out
    assert len(outcome.revolutions) >= 0.8 * (turns - 2), summary
    assert good >= 0.999 * total, summary
    fill = outcome.fill(kind)
    assert fill.min() >= min_fill, summary
    assert fill.max() <= 1.01, summary  # no two turns run together


# ---------------------------------------------------------------- synthesised streams


def test_clean_streams_give_whole_revolutions_on_the_profile() -> None:
    for kind in (STANDARD, EXPRESS, DENSE, ULTRA):
        outcome = run(kind, 6.0, seed=1, junk=False)
        good, total = outcome.on_profile(kind)
        assert good == total and len(outcome.revolutions) >= 4, outcome.summary(kind)
        assert np.all(np.abs(outcome.fill(kind) - 1) <= 0.01), outcome.summary(kind)


@pytest.mark.parametrize(("kind", "turns", "min_fill"), [
    pytest.param(STANDARD, 40.0, 0.90, id="standard"),
    pytest.param(EXPRESS, 40.0, 0.90, id="express"),
    pytest.param(DENSE, 15.0, 0.90, id="dense"),
    # one ultra capsule is 96 samples, 12 % of a 787-sample turn at 10 Hz: a turn that lost
    # the capsule hit by junk keeps one capsule less than 90 %
    pytest.param(ULTRA, 40.0, 1 - (ULTRA.per_record + 8) / ULTRA.per_revolution, id="ultra"),
])
@SEEDS
@given(seed=st.integers(0, 2**32 - 1))
def test_stream_with_junk(kind: Kind, turns: float, min_fill: float, seed: int) -> None:
    check_integrity(run(kind, turns, seed), kind, turns, min_fill)


# ---------------------------------------------------------------- one rule at a time


def parse(stream: bytes, chunk: int = 97) -> tuple[list[Revolution], StreamParser,
                                                  RevolutionAssembler, list[Event]]:
    parser, assembler = StreamParser(), RevolutionAssembler(sample_period=0.0005)
    revolutions: list[Revolution] = []
    events: list[Event] = []
    for at in range(0, len(stream), chunk):
        new = parser.feed(stream[at:at + chunk])
        events += new
        revolutions += assembler.feed(new, at * 1e-4)
    return revolutions, parser, assembler, events


def nodes_of(stream: bytes) -> list[bytes]:
    body = stream[7:]
    return [body[i:i + 5] for i in range(0, len(body), 5)]


def test_a_start_flag_without_a_wrap_does_not_cut_a_revolution() -> None:
    stream = stream_of(STANDARD, 6.0)
    nodes = nodes_of(stream)
    for i in (250, 333, 480, 700):  # valid nodes that claim a new revolution mid-turn
        nodes[i] = bytes((nodes[i][0] & 0xFC | 0b01,)) + nodes[i][1:]
    starts = [i for i, node in enumerate(nodes) if node[0] & 1 and i not in (250, 333, 480, 700)]
    lost = starts[2]  # a wrap whose start node was lost: the wrap still ends the turn
    nodes[lost] = bytes((nodes[lost][0] & 0xFC | 0b10,)) + nodes[lost][1:]
    revolutions, _, assembler, _ = parse(stream[:7] + b"".join(nodes))
    fill = np.array([len(r) for r in revolutions]) / STANDARD.per_revolution
    assert len(revolutions) == 5 and np.all(np.abs(fill - 1) <= 0.01), fill
    assert all(r.angle_deg[0] < STANDARD.step_deg for r in revolutions)
    assert assembler.short == 0


def test_the_held_back_node_is_emitted_when_the_stream_ends_cleanly() -> None:
    stream = stream_of(STANDARD, 1.5)
    health = Descriptor(3, False, Ans.HEALTH).encode() + bytes(3)
    _, _, _, events = parse(stream + health)
    count = sum(len(e) for e in events if isinstance(e, Samples))
    assert count == len(nodes_of(stream)) and isinstance(events[-1], Health)


def test_a_node_that_does_not_fit_is_dropped_and_counted() -> None:
    stream = stream_of(STANDARD, 4.0)
    nodes = nodes_of(stream)
    angle_q6 = (nodes[300][1] >> 1 | nodes[300][2] << 7) + 90 * 64  # passes its check bits
    nodes[300] = bytes((nodes[300][0], (angle_q6 & 0x7F) << 1 | 1, angle_q6 >> 7)) + nodes[300][3:]
    revolutions, parser, _, events = parse(stream[:7] + b"".join(nodes))
    samples = [e for e in events if isinstance(e, Samples)]
    angle = np.concatenate([e.angle_deg for e in samples])
    dist = np.concatenate([e.distance_mm for e in samples])
    assert on_profile(angle, dist, STANDARD.tolerance_mm).all()
    assert parser.angle_misfits == 1 and parser.resyncs == 1
    assert len(angle) >= len(nodes) - 4  # the misfit and the nodes next to it at most
    assert len(revolutions) == 3


def _with_start(capsule: bytes, start_q6: int) -> bytes:
    """The capsule with another start angle and a checksum that matches again."""
    body = bytes((start_q6 & 0xFF, start_q6 >> 8 | capsule[3] & 0x80)) + capsule[4:]
    chk = 0
    for byte in body:
        chk ^= byte
    return bytes((0xA0 | chk & 0xF, 0x50 | chk >> 4)) + body


@pytest.mark.parametrize("kind", [EXPRESS, DENSE, ULTRA], ids=["express", "dense", "ultra"])
def test_a_capsule_that_does_not_fit_is_dropped_and_counted(kind: Kind) -> None:
    stream = stream_of(kind, 3.0)
    body = stream[7:]
    caps = [body[i:i + kind.size] for i in range(0, len(body), kind.size)]
    hit = len(caps) // 2
    start = caps[hit][2] | (caps[hit][3] & 0x7F) << 8
    caps[hit] = _with_start(caps[hit], (start + 100 * 64) % records.FULL_TURN_Q6)
    revolutions, parser, _, events = parse(stream[:7] + b"".join(caps), chunk=1000)
    samples = [e for e in events if isinstance(e, Samples)]
    angle = np.concatenate([e.angle_deg for e in samples])
    dist = np.concatenate([e.distance_mm for e in samples])
    assert on_profile(angle, dist, kind.tolerance_mm).all()
    assert parser.angle_misfits == 1 and parser.dropped_capsules == 1
    # the capsule before the misfit is decoded with the advance before it: one capsule lost
    assert len(angle) >= (len(caps) - 3) * kind.per_record
    fill = np.array([len(r) for r in revolutions]) / kind.per_revolution
    assert len(revolutions) >= 1 and np.all((fill >= 0.8) & (fill <= 1.01)), fill


def test_a_revolution_far_short_of_a_whole_turn_is_counted_not_published() -> None:
    stream = stream_of(STANDARD, 5.0)
    nodes = nodes_of(stream)
    del nodes[460:560]  # half a turn lost on the line (whole nodes: the angle says so)
    revolutions, parser, assembler, _ = parse(stream[:7] + b"".join(nodes))
    fill = np.array([len(r) for r in revolutions]) / STANDARD.per_revolution
    assert len(revolutions) == 3 and np.all(fill >= 0.9), fill
    assert assembler.short == 1 and assembler.last_short is not None
    samples, expected = assembler.last_short
    assert samples < 0.6 * expected and abs(expected - STANDARD.per_revolution) < 2
    assert parser.angle_misfits == 1


def test_more_than_a_turn_lost_never_merges_two_turns() -> None:
    stream = stream_of(STANDARD, 8.0)
    nodes = nodes_of(stream)
    del nodes[500:800]  # 1.5 turns
    revolutions, _, assembler, _ = parse(stream[:7] + b"".join(nodes))
    fill = np.array([len(r) for r in revolutions]) / STANDARD.per_revolution
    assert len(revolutions) >= 4 and np.all((fill >= assembler.min_fill) & (fill <= 1.01)), fill
    assert assembler.short >= 1


def test_a_long_burst_of_junk_is_a_discontinuity() -> None:
    stream = stream_of(STANDARD, 6.0)
    junk = np.random.default_rng(3).integers(0, 256, 400).astype(np.uint8).tobytes()
    at = 7 + 5 * 500 + 2
    revolutions, _, assembler, events = parse(stream[:at] + junk + stream[at:])
    assert sum(isinstance(e, Discontinuity) for e in events) == 1
    assert assembler.discarded == 1  # the turn in progress could not be completed
    fill = np.array([len(r) for r in revolutions]) / STANDARD.per_revolution
    # six turns from 0°: five whole, less the one the junk fell into
    assert len(revolutions) == 4 and np.all((fill >= 0.99) & (fill <= 1.01)), fill


# ---------------------------------------------------------------- the real byte path (pty)


def emulated_world(angles_rad: F64, t: float) -> F64:
    result: F64 = profile_mm(np.rad2deg(angles_rad)) / 1000.0
    return result


def lidar_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "daemon.cli", "lidar", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=60, check=False)


@pytest.mark.parametrize(("mode", "kind"), [("standard", STANDARD), ("express", EXPRESS)])
def test_scan_json_through_a_flaky_cable(tmp_path: Path, mode: str, kind: Kind) -> None:
    """`arbiterd lidar scan --json` against the emulator on a pty with junk sprinkled in."""
    link = tmp_path / "rplidar"
    with RplidarEmulator(link, A1, ranges_fn=emulated_world, seed=5) as emulator:
        emulator.sprinkle_junk(kind.records_per_junk)
        done = lidar_cli("scan", "--port", str(link), "--mode", mode, "--revolutions", "12",
                         "--json")
    assert done.returncode == 0, done.stderr
    revs = [json.loads(line) for line in done.stdout.splitlines()]
    assert len(revs) == 12
    angle = np.concatenate([rev["angles_deg"] for rev in revs])
    ranges = np.array([r if r is not None else np.nan for rev in revs for r in rev["ranges_m"]])
    off = ~on_profile(angle, ranges * 1000, kind.tolerance_mm)
    fill = np.array([len(rev["angles_deg"]) for rev in revs]) / kind.per_revolution
    summary = f"{off.sum()}/{len(off)} samples off the profile, fill {np.round(fill, 3)}"
    assert off.sum() <= 0.001 * len(off), summary
    assert fill.min() >= 0.90 and fill.max() <= 1.01, summary


def health_when(manager: LidarManager, ok: Callable[[dict[str, Any]], bool],
                what: str) -> dict[str, Any]:
    """The manager's health once ``ok`` holds for it."""
    def check() -> dict[str, Any] | None:
        health = manager.snapshot()
        return health if ok(health) else None
    found: dict[str, Any] = wait_for(check, what, within_s=30.0)
    return found


def test_device_manager_through_a_flaky_cable_counts_and_recovers(tmp_path: Path) -> None:
    link = tmp_path / "rplidar"
    collector: Collector[Revolution] = Collector()
    config = ManagerConfig(port=str(link), scan_mode="standard", banner_timeout=0.5)
    manager = LidarManager(config, collector)
    with RplidarEmulator(link, A1, ranges_fn=emulated_world, seed=9) as emulator:
        emulator.sprinkle_junk(STANDARD.records_per_junk)
        manager.start()
        try:
            revs = collector.wait(15, "15 revolutions")
            health = manager.snapshot()
            emulator.sprinkle_junk(0)
            emulator.stall(0.05)  # half a turn lost, no junk: the angle jumps, a turn is short
            after_gap = health_when(
                manager, lambda h: h["short_revolutions"] > health["short_revolutions"],
                "a short revolution")
            emulator.stall(2.5)  # no revolution for 2 s: the stream is restarted
            restarting = health_when(manager, lambda h: h["stream_restarts"] > 0,
                                     "a stream restart")
            assert restarting["last_error"], restarting
            collector.wait(collector.count() + 3, "3 more revolutions")
            recovered = manager.snapshot()
        finally:
            manager.stop()
    angle = np.concatenate([r.angle_deg for r in revs])
    dist = np.concatenate([r.distance_mm for r in revs])
    off = ~on_profile(angle, dist, STANDARD.tolerance_mm)
    fill = np.array([len(r) for r in revs]) / STANDARD.per_revolution
    summary = f"{off.sum()}/{len(off)} samples off the profile, fill {np.round(fill, 3)}"
    assert off.sum() <= 0.001 * len(off), summary
    assert fill.min() >= 0.90 and fill.max() <= 1.01, summary
    assert health["status"] == "ok" and health["resyncs"] >= 5, health
    for key in ("dropped_nodes", "angle_misfits", "short_revolutions"):
        assert isinstance(health[key], int), (key, health)
    assert health["dropped_nodes"] >= 5 and health["angle_misfits"] >= 1, health
    # the half turn lost is counted as a short revolution (the wait above) and not published;
    # how the jump itself is counted (misfit, resync, relock) depends on where the stall cut
    # the stream, so it is asserted by the parser's unit tests, not here
    assert after_gap["short_revolutions"] > health["short_revolutions"], after_gap
    assert recovered["status"] == "ok" and recovered["last_error"] is None, recovered


@pytest.mark.parametrize("kind", [DENSE, ULTRA], ids=["dense", "ultra"])
def test_a_shortened_capsule_that_passes_its_check_does_not_hide_its_successor(
        kind: Kind) -> None:
    """A capsule that lost 3 bytes, read with its successor's first 3, passes the 8-bit check
    (once in 256 by chance; made so here): it is accepted, the next read fails, and the hunt
    must still find the intact successor starting inside it."""
    stream = stream_of(kind, 1.0)
    body = stream[7:]
    caps = [body[i:i + kind.size] for i in range(0, len(body), kind.size)]
    hit = len(caps) // 2
    short = bytearray(caps[hit][:40] + caps[hit][43:])
    window = bytes(short) + caps[hit + 1][:3]  # what a reader locked on the old phase takes
    chk = 0
    for byte in window[2:]:
        chk ^= byte
    short[50] ^= chk ^ ((window[0] & 0xF) | (window[1] & 0xF) << 4)
    assert records.capsule_check(np.frombuffer(bytes(short) + caps[hit + 1][:3],
                                               np.uint8)[None, :])[0]
    caps[hit] = bytes(short)
    clean = _sample_rows(parse(stream, chunk=1000)[3])
    got = _sample_rows(parse(stream[:7] + b"".join(caps), chunk=1000)[3])
    per = kind.per_record
    successor = clean[(hit + 1) * per:(hit + 2) * per]  # decoded with its own successor
    assert len(successor) == per and set(successor) <= set(got), "the successor was lost"
    # lost: the shortened capsule (never decoded) and the last one (it has no successor)
    assert len(got) == (len(caps) - 2) * per


def _sample_rows(events: list[Event]) -> list[tuple[float, float]]:
    samples = [e for e in events if isinstance(e, Samples)]
    return list(zip(np.concatenate([e.angle_deg for e in samples]).tolist(),
                    np.concatenate([e.distance_mm for e in samples]).tolist(), strict=True))
