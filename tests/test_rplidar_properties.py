# Property tests: random scans per record type, cut anywhere, corrupted anywhere; the parser
# recovers every intact record and never raises.
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sensors.rplidar import synth
from sensors.rplidar.requests import Ans
from sensors.rplidar.streams import Event, Samples, StreamParser

SETTINGS = settings(max_examples=150, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
CAPSULE_TYPES = [Ans.CAPSULE, Ans.DENSE_CAPSULE, Ans.ULTRA_CAPSULE]
SIZES: dict[int, int] = {
    Ans.NODE: 5, Ans.CAPSULE: 84, Ans.DENSE_CAPSULE: 84, Ans.ULTRA_CAPSULE: 132,
}


@dataclass
class Scan:
    data_type: int
    records: list[bytes]
    angle_deg: np.ndarray  # what was encoded, per sample
    distance_mm: np.ndarray


@st.composite
def node_scans(draw: st.DrawFn) -> Scan:
    n = draw(st.integers(8, 120))
    step = draw(st.floats(0.3, 5.0))
    jitter = np.array(draw(st.lists(st.floats(-0.2, 0.2), min_size=n, max_size=n)))
    angle = (draw(st.floats(0, 359)) + np.cumsum(step * (1 + jitter))) % 360
    dist_q2 = np.array(draw(st.lists(st.integers(0, 65535), min_size=n, max_size=n)))
    quality = np.array(draw(st.lists(st.integers(0, 63), min_size=n, max_size=n)))
    start = np.r_[False, np.diff(angle) < 0]
    body = synth.encode_nodes(angle, dist_q2 / 4, quality, start)
    return Scan(Ans.NODE, [body[i:i + 5] for i in range(0, len(body), 5)],
                np.rint(angle * 64) % 23040 / 64, dist_q2 / 4)


@st.composite
def capsule_scans(draw: st.DrawFn, data_type: int) -> Scan:
    k = draw(st.integers(3, 10))
    per = synth.SAMPLES_PER_CAPSULE[data_type]
    # a rotor turns steadily: the start-angle advance jitters by at most 20 % around its mean
    mean = draw(st.integers(64, 40 * 64))
    jitter = np.array(draw(st.lists(st.floats(-0.2, 0.2), min_size=k, max_size=k)))
    deltas = np.rint(mean * (1 + jitter)).astype(int).tolist()
    start_q6 = (draw(st.integers(0, 23039)) + np.cumsum([0, *deltas[:-1]])) % 23040
    sync = np.arange(k) == 0
    if data_type == Ans.ULTRA_CAPSULE:  # smooth ranges: predictions are bounded
        base = draw(st.integers(60, 20000))
        slopes = draw(st.lists(st.integers(-3, 3), min_size=k * per, max_size=k * per))
        dist = np.clip(base + np.cumsum(slopes), 0, 25000).reshape(k, per)
        body = synth.encode_ultra(start_q6, dist, sync, next_first_mm=int(dist[-1, -1]))
    else:
        top = 16383 if data_type == Ans.CAPSULE else 65535
        dist = np.array(draw(st.lists(st.integers(0, top), min_size=k * per,
                                      max_size=k * per))).reshape(k, per)
        if data_type == Ans.CAPSULE:
            dtheta = np.array(draw(st.lists(st.integers(0, 63), min_size=k * per,
                                            max_size=k * per))).reshape(k, per)
            body = synth.encode_legacy(start_q6, dist, dtheta, sync)
        else:
            body = synth.encode_dense(start_q6, dist, sync)
    size = SIZES[data_type]
    return Scan(data_type, [body[i:i + size] for i in range(0, len(body), size)],
                np.empty(0), dist.reshape(-1).astype(float))


def any_scan() -> st.SearchStrategy[Scan]:
    return st.one_of(node_scans(), *[capsule_scans(t) for t in CAPSULE_TYPES])


def decode(stream: bytes, cuts: list[int]) -> tuple[list[Samples], StreamParser]:
    parser = StreamParser()
    events: list[Event] = []
    bounds = [0, *sorted(c % (len(stream) + 1) for c in cuts), len(stream)]
    for a, b in itertools.pairwise(bounds):
        events += parser.feed(stream[a:b])
    return [e for e in events if isinstance(e, Samples)], parser


def sample_rows(runs: list[Samples]) -> list[tuple[int, float, int]]:
    rows: list[tuple[int, float, int]] = []
    for run in runs:
        q6 = np.rint(run.angle_deg * 64).astype(int)
        rows += zip(q6.tolist(), run.distance_mm.tolist(), run.quality.tolist(), strict=True)
    return rows


Row = tuple[int, float, int]


def is_subsequence(needles: list[Row], hay: list[Row]) -> bool:
    it = iter(hay)
    return all(any(x == y for y in it) for x in needles)


def stream_of(scan: Scan, records: list[bytes], junk: bytes = b"") -> bytes:
    desc = synth.STREAM_DESCRIPTORS[scan.data_type].encode()
    return junk + desc + b"".join(records)


def per_record_rows(scan: Scan) -> list[list[tuple[int, float, int]]]:
    """Clean decode split per record (a record waits for its successor to be judged, and a
    capsule's samples need its successor's start angle: the last one is not decoded)."""
    runs, _ = decode(stream_of(scan, scan.records), [])
    rows = sample_rows(runs)
    per = 1 if scan.data_type == Ans.NODE else synth.SAMPLES_PER_CAPSULE[scan.data_type]
    decodable = len(scan.records) - 1
    assert len(rows) == decodable * per
    return [rows[i * per:(i + 1) * per] for i in range(decodable)]


# ---------------------------------------------------------------- properties


@SETTINGS
@given(scan=any_scan(), banner=st.binary(max_size=80))
def test_clean_decode_matches_what_was_encoded(scan: Scan, banner: bytes) -> None:
    runs, parser = decode(stream_of(scan, scan.records, b"RP LIDAR System.\r\n" + banner), [])
    dist = np.concatenate([r.distance_mm for r in runs])
    if scan.data_type == Ans.NODE:  # the last node waits for a successor to be judged
        angle = np.concatenate([r.angle_deg for r in runs])
        assert np.array_equal(angle, scan.angle_deg[:-1])
        assert np.array_equal(dist, scan.distance_mm[:-1])
    else:
        per = synth.SAMPLES_PER_CAPSULE[scan.data_type]
        want = scan.distance_mm[:len(scan.distance_mm) - per]
        # ultra: the scale level is the prediction base's (a neighbour within a few mm)
        near = np.maximum(want, dist) + 8
        tolerance = 0 if scan.data_type != Ans.ULTRA_CAPSULE else _ultra_quantum(near)
        assert np.all(np.abs(dist - want) <= tolerance)
    assert parser.resyncs == 0 and parser.dropped_capsules == 0


def _ultra_quantum(dist: np.ndarray) -> np.ndarray:
    """Half a VBS step for predictions, a whole one for majors (they round down)."""
    return np.select([dist >= 16384, dist >= 4096, dist >= 2048, dist >= 512],
                     [16, 8, 4, 2], 0).astype(float)


@SETTINGS
@given(scan=any_scan(), cuts=st.lists(st.integers(0, 10**6), max_size=12))
def test_any_chunking_gives_the_same_records(scan: Scan, cuts: list[int]) -> None:
    stream = stream_of(scan, scan.records, b"junk\x00\xa5")
    whole, _ = decode(stream, [])
    chunked, _ = decode(stream, cuts)
    assert sample_rows(chunked) == sample_rows(whole)


@st.composite
def corruptions(draw: st.DrawFn, count: int) -> dict[int, tuple[str, bytes, int]]:
    hits = draw(st.lists(st.integers(0, count - 1), max_size=max(1, count // 4), unique=True))
    ops: dict[int, tuple[str, bytes, int]] = {}
    for index in hits:
        kind = draw(st.sampled_from(["insert", "drop", "flip"]))
        junk = draw(st.binary(min_size=1, max_size=40))
        ops[index] = (kind, junk, draw(st.integers(0, 10**6)))
    return ops


def corrupt(records: list[bytes], ops: dict[int, tuple[str, bytes, int]]) -> tuple[list[bytes],
                                                                                  set[int]]:
    """Apply the ops; returns the new record byte strings and the indices still intact."""
    out: list[bytes] = []
    intact = set(range(len(records)))
    for i, rec in enumerate(records):
        kind, junk, at = ops.get(i, ("none", b"", 0))
        if kind == "insert":
            out.append(junk + rec)  # junk before record i, record i intact
            continue
        if kind == "drop":
            cut = at % len(rec)
            rec = rec[:cut] + rec[cut + 1 + at % min(3, len(rec) - cut):]
            intact.discard(i)
        elif kind == "flip":
            cut = at % len(rec)
            flipped = rec[cut] ^ (junk[0] or 0x40)
            rec = rec[:cut] + bytes((flipped,)) + rec[cut + 1:]
            intact.discard(i)
        out.append(rec)
    return out, intact


def recoverable(scan: Scan, ops: dict[int, tuple[str, bytes, int]], intact: set[int],
                lock_nodes: int) -> list[int]:
    """Records the parser must deliver: nodes in untouched runs of at least ``lock_nodes``
    (a byte phase is accepted only then) but the first and last of each (the nodes next to
    damage are dropped); capsules whose successor is also untouched and adjacent."""
    count = len(scan.records)

    def joined(i: int) -> bool:  # record i+1 follows record i with nothing inserted
        return i + 1 < count and i in intact and i + 1 in intact and \
            ops.get(i + 1, ("",))[0] != "insert"

    if scan.data_type != Ans.NODE:
        return [i for i in range(count - 1) if joined(i)]
    runs: list[list[int]] = []
    for i in range(count):
        if i in intact and runs and runs[-1][-1] == i - 1 and joined(i - 1):
            runs[-1].append(i)
        elif i in intact:
            runs.append([i])
    return [i for run in runs if len(run) >= lock_nodes for i in run[1:-1]]


@SETTINGS
@given(scan=any_scan(), data=st.data(), cuts=st.lists(st.integers(0, 10**6), max_size=6))
def test_corruption_never_loses_intact_records(scan: Scan, data: st.DataObject,
                                                cuts: list[int]) -> None:
    ops = data.draw(corruptions(len(scan.records)))
    records, intact = corrupt(scan.records, ops)
    clean = per_record_rows(scan)
    runs, parser = decode(stream_of(scan, records, data.draw(st.binary(max_size=30))), cuts)
    got = sample_rows(runs)
    must = recoverable(scan, ops, intact, parser.lock_nodes)
    expected = [row for i in must for row in clean[i]]
    assert is_subsequence(expected, got), f"lost records among {must}"
    if scan.data_type != Ans.NODE:
        # a damaged capsule right after an intact one is met while locked: dropped and counted
        counted = [i for i, (kind, _, _) in ops.items()
                   if kind != "insert" and i - 1 in intact and i + 1 < len(records)]
        assert parser.dropped_capsules >= min(len(counted), 1)


@SETTINGS
@given(noise=st.binary(max_size=3000), cuts=st.lists(st.integers(0, 10**6), max_size=8),
       prefix=st.sampled_from([b"", *[synth.STREAM_DESCRIPTORS[t].encode()
                                      for t in [Ans.NODE, *CAPSULE_TYPES]]]))
def test_random_bytes_never_raise(noise: bytes, cuts: list[int], prefix: bytes) -> None:
    runs, parser = decode(prefix + noise, cuts)
    for run in runs:
        assert np.all((run.angle_deg >= 0) & (run.angle_deg < 360))
        assert np.all(run.distance_mm >= 0)
    assert parser.stats.junk_bytes <= len(prefix) + len(noise)
