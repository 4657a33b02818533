# RPLIDAR measurement streams: a pure, resynchronising parser of nodes and capsules (no I/O).
from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sensors.rplidar import records
from sensors.rplidar.records import U8
from sensors.rplidar.requests import (
    DESCRIPTOR_SIZE,
    DESCRIPTOR_SYNC,
    Ans,
    Descriptor,
    Reply,
    parse_descriptor,
    parse_reply,
)

# ---------------------------------------------------------------- events


@dataclass(frozen=True)
class UnsupportedStream:
    """A measurement stream of a type this parser does not decode; its bytes are skipped."""

    data_type: int


@dataclass(frozen=True)
class EncoderReset:
    """A capsule with S set mid-stream: the device reset its encoder; the revolution restarts."""


@dataclass(frozen=True)
class Discontinuity:
    """Too many bytes were lost for the angle to tell how far the rotor turned meanwhile: the
    revolution in progress cannot be completed."""


@dataclass
class Samples:
    """A run of decoded samples in device order; ``new_rev`` marks the first sample of a turn.

    ``lag``: samples the device sent after this run that the parser still holds back (the next
    node, or the capsule that completes the last one), for timing the run.
    """

    data_type: int
    angle_deg: records.F64
    distance_mm: records.F64
    quality: U8
    new_rev: records.Bools
    lag: int = 0

    def __len__(self) -> int:
        return len(self.angle_deg)


Event = Descriptor | Reply | UnsupportedStream | EncoderReset | Discontinuity | Samples


# ---------------------------------------------------------------- measurement streams


class _RecordStream:
    """Per-type record decoder: locked to a byte phase, or hunting for one.

    While locked, a record is accepted when it passes its check and its angle fits the one
    before it; the last accepted record is held back ("pending") until its successor is
    judged. ``backtrack``: how many bytes before the decode position the buffer keeps, for a
    hunt that restarts back there after a record fails (``hunt_from``; 0: one byte after the
    failed record).
    """

    size = 1
    backtrack = 0

    def __init__(self, data_type: int) -> None:
        self.data_type = data_type
        self.locked = False
        self.resyncs = 0  # records that failed while locked
        self.dropped = 0  # records not published (see the subclasses)
        self.misfits = 0  # failed records that passed their check but not the angle test

    def valid(self, recs: U8) -> records.Bools:
        """Per record: check passed and angle fits the record before it."""
        raise NotImplementedError

    def find_lock(self, buf: U8, pos: int) -> tuple[int | None, int]:
        """(lock position or None, first position still undecided)."""
        raise NotImplementedError

    def on_lock(self, lock: int) -> list[Event]:
        """The parser locked at ``lock`` (a position ``find_lock`` returned)."""
        self.locked = True
        return []

    def accept(self, buf: U8, pos: int, count: int) -> list[Event]:
        """``count`` records from ``pos`` are valid: emit what is no longer pending."""
        raise NotImplementedError

    def lose_sync(self, rec: U8, passed_check: bool) -> None:
        """The record ``rec`` failed (its check, or only its angle when ``passed_check``)."""
        self.locked = False
        self.resyncs += 1
        self.misfits += passed_check

    def check(self, rec: U8) -> bool:
        raise NotImplementedError

    def finish(self, buf: U8, pos: int) -> list[Event]:
        """A new descriptor follows at ``pos``: the stream ended cleanly."""
        return []

    def hunt_from(self, pos: int) -> int:
        """Where the hunt restarts after the record at ``pos`` failed (before ``lose_sync``)."""
        return max(pos - self.backtrack, 0) if self.backtrack else pos + 1

    def shift(self, dropped: int) -> None:
        """The parser dropped ``dropped`` bytes from the front of its buffer."""


def _budget(gap: records.I64 | int, size: int, unit_q6: int) -> records.I64:
    """Largest angle advance (q6) across ``gap`` bytes since the end of the last accepted record:
    one ``unit_q6`` per record that can have been lost there, plus one."""
    return (np.maximum(np.asarray(gap) + size - 1, 0) // size + 1) * unit_q6


class _NodeStream(_RecordStream):
    """Standard nodes. After a failed node the hunt restarts ``backtrack_nodes`` back, in the
    byte phases not yet emitted there: a slipped phase can pass the 2 check bits for a few nodes and
    swallow intact ones. A lock needs ``lock_nodes`` valid nodes whose angle steps are within
    [``min_step``, ``max_step``] and within a factor ``STEP_SPREAD`` of each other, and whose first
    angle fits the last emitted node across the bytes between them. While locked, each step must
    be at most ``STEP_SPREAD`` times the largest lock step (or back by at most ``BACK_TOL_Q6``).
    The nodes next to junk are dropped: the one before a failed node (junk inside a node's
    distance bytes passes every test) and the first of a lock after a failure (it may be the
    tail of the node the junk was inserted into). A revolution starts where the angle wraps."""

    size = records.NODE_SIZE
    STEP_SPREAD = 4
    MIN_STEP_Q6 = 3  # 0.047°: finer than any standard-mode device samples
    BACK_TOL_Q6 = 64  # 1°: jitter allowed backwards; a larger fall is a wrap past 0°

    def __init__(self, lock_nodes: int, max_step_q6: int, backtrack_nodes: int = 8) -> None:
        super().__init__(Ans.NODE)
        self.lock_nodes = lock_nodes
        self.max_step_q6 = max_step_q6
        self.max_fit_q6 = max_step_q6
        self.backtrack = backtrack_nodes * self.size - 1
        self.emitted_end: dict[int, int] = {}  # byte phase -> end of the records emitted in it
        self.anchor_q6: int | None = None  # angle of the last emitted node
        self.anchor_end = 0  # buffer position just after it
        self.pending = False  # the node just before the decode position is held back
        self.pending_q6 = 0
        self.skip_first = False  # drop the first node of the lock just taken
        self._relock = False  # the next lock follows a failure
        self._lock_step = 0
        self._lock_far = False
        self._angle: records.I64 = np.zeros(0, dtype=np.int64)  # q6 of the records last judged

    def check(self, rec: U8) -> bool:
        return bool(records.node_check(rec[0:1], rec[1:2], rec[2:3])[0])

    def valid(self, recs: U8) -> records.Bools:
        b0, b1 = recs[:, 0], recs[:, 1]
        angle = records.node_angle_q6(b1, recs[:, 2])
        ok = (((b0 ^ (b0 >> 1)) & b1 & 1).astype(bool)) & (angle < records.FULL_TURN_Q6)
        prev = np.empty_like(angle)
        prev[1:] = angle[:-1]
        prev[0] = self.pending_q6 if self.pending else angle[0]
        step = np.mod(angle - prev, records.FULL_TURN_Q6)
        fits = (step <= self.max_fit_q6) | (step >= records.FULL_TURN_Q6 - self.BACK_TOL_Q6)
        self._angle = angle
        return ok & fits

    def find_lock(self, buf: U8, pos: int) -> tuple[int | None, int]:
        count = len(buf) - pos - self.size * self.lock_nodes + 1
        if count <= 0:
            return None, pos
        tail = buf[pos:]
        ok = records.node_check(tail[:-4], tail[1:-3], tail[2:-2])
        angle = records.node_angle_q6(tail[1:-3], tail[2:-2])
        cand = ok[:count].copy()
        lo = np.full(count, records.FULL_TURN_Q6, dtype=np.int64)
        hi = np.zeros(count, dtype=np.int64)
        for j in range(1, self.lock_nodes):
            at, before = j * self.size, (j - 1) * self.size
            step = np.mod(angle[at:at + count] - angle[before:before + count], records.FULL_TURN_Q6)
            cand &= ok[at:at + count]
            lo, hi = np.minimum(lo, step), np.maximum(hi, step)
        cand &= (lo >= self.MIN_STEP_Q6) & (hi <= self.max_step_q6) & (hi <= self.STEP_SPREAD * lo)
        self._exclude_failed_phase(cand, pos)
        far = self._fit_anchor(cand, angle[:count], pos)
        hits = np.flatnonzero(cand)
        if len(hits):
            hit = int(hits[0])
            self._lock_step, self._lock_far = int(hi[hit]), bool(far[hit])
            return pos + hit, pos + hit
        return None, pos + count

    def _fit_anchor(self, cand: records.Bools, angle: records.I64, pos: int) -> records.Bools:
        """Keep candidates whose angle fits the last emitted node; True where too many bytes
        passed since it for its angle to say anything (the revolution is then lost)."""
        if self.anchor_q6 is None:
            return np.ones(len(cand), dtype=bool)
        gap = pos + np.arange(len(cand)) - self.anchor_end
        budget = _budget(gap, self.size, self.max_fit_q6)
        far: records.Bools = budget >= records.FULL_TURN_Q6 - self.BACK_TOL_Q6
        advance = np.mod(angle - self.anchor_q6, records.FULL_TURN_Q6)
        cand &= far | (advance <= budget) | (advance >= records.FULL_TURN_Q6 - self.BACK_TOL_Q6)
        return far

    def _exclude_failed_phase(self, cand: records.Bools, pos: int) -> None:
        """Never lock where a record of the same byte phase was already emitted."""
        for end in self.emitted_end.values():
            if end > pos:
                first = (end - pos) % self.size
                cand[first:min(end - pos, len(cand)):self.size] = False

    def on_lock(self, lock: int) -> list[Event]:
        self.locked = True
        self.skip_first = self._relock
        self.max_fit_q6 = min(self.STEP_SPREAD * self._lock_step, self.max_step_q6)
        if self._lock_far and self.anchor_q6 is not None:
            self.anchor_q6 = None
            return [Discontinuity()]
        return []

    def accept(self, buf: U8, pos: int, count: int) -> list[Event]:
        angle = self._angle[:count - 1]  # the last valid node stays pending
        first = pos - self.size if self.pending else pos
        if self.pending:
            angle = np.concatenate([[self.pending_q6], angle])
        elif self.skip_first:
            self.skip_first, self.dropped = False, self.dropped + 1
            if count == 1:
                return []
            first, angle = pos + self.size, angle[1:]
        end = pos + (count - 1) * self.size
        self.pending, self.pending_q6 = True, int(self._angle[count - 1])
        if end <= first:
            return []
        return [self._emit(buf[first:end].reshape(-1, self.size), angle, first)]

    def _emit(self, recs: U8, angle_q6: records.I64, first: int, lag: int = 1) -> Samples:
        """Samples of ``recs`` (from buffer position ``first``), whose angles are known."""
        end = first + len(recs) * self.size
        self.emitted_end[first % self.size] = end
        prev = np.empty_like(angle_q6)
        prev[1:] = angle_q6[:-1]
        prev[0] = self.anchor_q6 if self.anchor_q6 is not None else 0
        new_rev = angle_q6 + self.BACK_TOL_Q6 < prev
        if self.anchor_q6 is None:
            new_rev[0] = bool(recs[0, 0] & 1)  # nothing to compare with: trust the S flag
        self.anchor_q6, self.anchor_end = int(angle_q6[-1]), end
        dist = (recs[:, 3].astype(np.int64) | (recs[:, 4].astype(np.int64) << 8)) / 4.0
        return Samples(self.data_type, angle_q6 / 64.0, dist, (recs[:, 0] >> 2).astype(np.uint8),
                       new_rev, lag)

    def lose_sync(self, rec: U8, passed_check: bool) -> None:
        super().lose_sync(rec, passed_check)
        self._relock = True
        if self.pending:
            self.dropped += 1
            self.pending = False

    def finish(self, buf: U8, pos: int) -> list[Event]:
        if not self.pending:
            return []
        self.pending = False
        return [self._emit(buf[pos - self.size:pos].reshape(1, self.size),
                           np.array([self.pending_q6], dtype=np.int64), pos - self.size, lag=0)]

    def shift(self, dropped: int) -> None:
        self.emitted_end = {(end - dropped) % self.size: end - dropped
                            for end in self.emitted_end.values() if end - dropped > 0}
        self.anchor_end -= dropped


_CAPSULE_DECODERS: dict[int, tuple[int, Callable[[U8, U8], records.DecodedSamples]]] = {
    Ans.CAPSULE: (records.LEGACY_SIZE, records.decode_legacy),
    Ans.DENSE_CAPSULE: (records.DENSE_SIZE, records.decode_dense),
    Ans.ULTRA_CAPSULE: (records.ULTRA_SIZE, records.decode_ultra),
}
# samples at the end of a capsule that depend on its successor's body (ultra: next major)
_SUCCESSOR_SAMPLES: dict[int, int] = {Ans.CAPSULE: 0, Ans.DENSE_CAPSULE: 0, Ans.ULTRA_CAPSULE: 2}


class _CapsuleStream(_RecordStream):
    """Capsules decode in pairs (a capsule needs its successor's start angle): one of latency.

    The start angle of each capsule must advance from its predecessor's by 1/2..2 times the
    previous advance (``MAX_SPAN_Q6`` when that is unknown); a capsule with S set (encoder
    reset) is exempt. When a capsule fails, its intact predecessor is decoded with the previous
    advance, but only once the hunt finds the next capsule at least a whole capsule further on:
    nearer, the junk may have been inside the predecessor itself.
    """

    MAX_SPAN_Q6 = 120 * 64
    SPAN_SLACK_Q6 = 64

    def __init__(self, data_type: int) -> None:
        super().__init__(data_type)
        self.size, self._decode = _CAPSULE_DECODERS[data_type]
        self.backtrack = self.size - 1
        self.per_capsule = len(self._decode(np.zeros((1, self.size), np.uint8),
                                            np.zeros((1, self.size), np.uint8)).angle_deg)
        self.previous: U8 | None = None  # last accepted capsule, waiting for its successor
        self.previous_confirmed = False  # it followed an accepted capsule (it is no lone lock)
        self.last_base_q16: int | None = None
        self.anchor_q6: int | None = None  # start angle of the last accepted capsule
        self.anchor_end = 0  # buffer position just after it
        self.span_q6: int | None = None  # start-angle advance between the last two capsules
        self.orphan: U8 | None = None  # an accepted capsule whose successor failed
        self._lock_far = False
        self._spans: records.I64 = np.zeros(0, dtype=np.int64)

    def check(self, rec: U8) -> bool:
        return bool(records.capsule_check(rec[None, :])[0])

    def valid(self, recs: U8) -> records.Bools:
        starts = records.capsule_start_q6(recs)
        sync = records.capsule_sync(recs)
        prev = np.empty_like(starts)
        prev[1:] = starts[:-1]
        has_prev = self.previous is not None
        prev[0] = self.anchor_q6 if has_prev and self.anchor_q6 is not None else starts[0]
        span = np.mod(starts - prev, records.FULL_TURN_Q6)
        before = np.empty_like(span)  # the advance each one is compared with
        before[1:] = span[:-1]
        known = np.ones(len(span), dtype=bool)
        before[0], known[0] = self.span_q6 or 0, self.span_q6 is not None
        if not has_prev and len(span) > 1:
            before[1], known[1] = before[0], known[0]
        known[1:] &= ~sync[:-1]
        fits = np.where(known, (2 * span >= before - self.SPAN_SLACK_Q6)
                        & (span <= 2 * before + self.SPAN_SLACK_Q6), span <= self.MAX_SPAN_Q6)
        fits |= sync
        fits[0] |= not has_prev
        measured = np.ones(len(span), dtype=bool)  # the advance comes from two capsules
        measured[0] = has_prev
        self._spans = np.where(sync | ~measured, -1, span)
        return records.capsule_check(recs) & fits

    def find_lock(self, buf: U8, pos: int) -> tuple[int | None, int]:
        tail = buf[pos:]
        marks = np.flatnonzero(((tail[:-1] >> 4) == 0xA) & ((tail[1:] >> 4) == 0x5))
        for mark in marks.tolist():
            at = pos + mark
            if at + self.size > len(buf):
                return None, at
            rec = buf[at:at + self.size]
            if self.check(rec) and self._fits_anchor(rec, at):
                return at, at
        return None, max(pos, len(buf) - 1)

    def _fits_anchor(self, rec: U8, at: int) -> bool:
        """Does a lock candidate continue from the last accepted capsule? Sets ``_lock_far``."""
        self._lock_far = True
        if self.anchor_q6 is None or rec[3] & 0x80:
            return True
        unit = self.MAX_SPAN_Q6 if self.span_q6 is None else 2 * self.span_q6 + self.SPAN_SLACK_Q6
        budget = int(_budget(at - self.anchor_end, self.size, unit))
        if budget >= records.FULL_TURN_Q6:
            return True
        self._lock_far = False
        start = int(rec[2]) | (int(rec[3] & 0x7F) << 8)
        return (start - self.anchor_q6) % records.FULL_TURN_Q6 <= budget

    def on_lock(self, lock: int) -> list[Event]:
        self.locked = True
        orphan, self.orphan = self.orphan, None
        events: list[Event] = []
        if self._lock_far:
            if self.anchor_q6 is not None:
                events.append(Discontinuity())
            self.anchor_q6 = self.span_q6 = self.last_base_q16 = None
        elif orphan is not None and lock - self.anchor_end >= self.size:
            events.append(self._orphan_samples(orphan))
            orphan = None
        self.dropped += orphan is not None
        return events

    def accept(self, buf: U8, pos: int, count: int) -> list[Event]:
        recs = buf[pos:pos + count * self.size].reshape(count, self.size)
        last_span = int(self._spans[count - 1])
        if last_span >= 0:
            self.span_q6 = last_span
        elif recs[-1, 3] & 0x80:
            self.span_q6 = None
        self.previous_confirmed = count > 1 or self.previous is not None
        self.anchor_q6 = int(records.capsule_start_q6(recs[-1:])[0])
        self.anchor_end = pos + count * self.size
        return self.emit(recs)

    def lose_sync(self, rec: U8, passed_check: bool) -> None:
        super().lose_sync(rec, passed_check)
        self.dropped += 1
        if self.previous is not None and self.previous_confirmed and self.span_q6 is not None:
            self.orphan = self.previous
        else:
            self.dropped += self.previous is not None
        self.previous = None

    def shift(self, dropped: int) -> None:
        self.anchor_end -= dropped

    def hunt_from(self, pos: int) -> int:
        """Inside the capsule accepted just before ``pos``, if any (the buffer keeps
        ``backtrack`` bytes for it): a damaged capsule passes the 8-bit checksum once in 256,
        and a capsule shortened by the damage then ends inside its intact successor, which the
        hunt must still find."""
        return max(pos - self.backtrack, 0) if self.previous is not None else pos + 1

    def emit(self, recs: U8) -> list[Event]:
        caps = recs if self.previous is None else np.concatenate([self.previous[None, :], recs])
        events: list[Event] = []
        resets = np.flatnonzero(records.capsule_sync(caps[1:])) + 1
        bounds = [0, *resets.tolist(), len(caps)]
        for first, end in itertools.pairwise(bounds):
            if first > 0:
                events.append(EncoderReset())
                self.last_base_q16 = None
            if end - first >= 2:
                events.append(self._samples(self._decode(caps[first:end - 1],
                                                         caps[first + 1:end])))
        self.previous = caps[-1].copy()
        return events

    def _orphan_samples(self, orphan: U8) -> Samples:
        """Decode a capsule whose successor was lost with the previous advance instead."""
        assert self.span_q6 is not None
        successor = orphan.copy()
        start = (int(records.capsule_start_q6(orphan[None, :])[0]) + self.span_q6) \
            % records.FULL_TURN_Q6
        successor[2], successor[3] = start & 0xFF, start >> 8
        decoded = self._decode(orphan[None, :], successor[None, :])
        keep = self.per_capsule - _SUCCESSOR_SAMPLES[self.data_type]
        return self._samples(records.DecodedSamples(
            decoded.angle_deg[:keep], decoded.distance_mm[:keep], decoded.quality[:keep],
            decoded.base_q16[:keep]), lag=0)

    def _samples(self, decoded: records.DecodedSamples, lag: int | None = None) -> Samples:
        base = decoded.base_q16
        previous = base[0] if self.last_base_q16 is None else self.last_base_q16
        new_rev = base < np.concatenate([[previous], base[:-1]])
        self.last_base_q16 = int(base[-1])
        return Samples(self.data_type, decoded.angle_deg, decoded.distance_mm, decoded.quality,
                       new_rev, self.per_capsule if lag is None else lag)


# ---------------------------------------------------------------- the parser


@dataclass
class ParserStats:
    """Totals of the streams already left (the live stream's counts are added on access)."""

    junk_bytes: int = 0
    resyncs: int = 0  # records that failed while locked
    dropped_capsules: int = 0  # failed capsules, and accepted ones that could not be decoded
    dropped_nodes: int = 0  # valid nodes dropped because the next one failed
    angle_misfits: int = 0  # records that passed their check but not the angle test
    records: int = 0
    samples: int = 0
    descriptors: int = 0


@dataclass
class StreamParser:
    """Bytes in (any chunking), events out. Never raises on device bytes.

    Skips banners and junk by hunting ``A5 5A``; reads single replies; follows measurement
    streams with per-type resynchronisation. ``lock_nodes`` consecutive valid standard nodes,
    each advancing the angle by more than 0 and at most ``max_node_step_deg``, are needed
    before a byte phase is accepted. A record is held back until the one after it is judged
    (docs/lidar.md, "Stream integrity").
    """

    lock_nodes: int = 4
    max_node_step_deg: float = 20.0
    stats: ParserStats = field(default_factory=ParserStats)
    _buf: bytes = b""
    _single: Descriptor | None = None
    _stream: _RecordStream | None = None
    _skip_stream: bool = False
    _resume: int = 0

    def reset(self) -> None:
        """Forget any stream and buffered bytes: the next thing expected is a descriptor."""
        self._fold_stream_stats()
        self._buf, self._single, self._stream, self._skip_stream = b"", None, None, False
        self._resume = 0

    @property
    def streaming(self) -> int | None:
        """The data type of the measurement stream being followed, if any."""
        return self._stream.data_type if self._stream else None

    @property
    def resyncs(self) -> int:
        return self.stats.resyncs + (self._stream.resyncs if self._stream else 0)

    @property
    def dropped_capsules(self) -> int:
        live = self._stream.dropped if isinstance(self._stream, _CapsuleStream) else 0
        return self.stats.dropped_capsules + live

    @property
    def dropped_nodes(self) -> int:
        live = self._stream.dropped if isinstance(self._stream, _NodeStream) else 0
        return self.stats.dropped_nodes + live

    @property
    def angle_misfits(self) -> int:
        return self.stats.angle_misfits + (self._stream.misfits if self._stream else 0)

    def feed(self, data: bytes) -> list[Event]:
        self._buf += data
        events: list[Event] = []
        while self._step(events):
            pass
        for event in events:
            if isinstance(event, Samples):
                self.stats.samples += len(event)
        return events

    # -- states

    def _step(self, events: list[Event]) -> bool:
        if self._skip_stream:
            self.stats.junk_bytes += len(self._buf)
            self._buf = b""
            return False
        if self._single is not None:
            return self._read_single(events)
        if self._stream is not None:
            return self._read_stream(events)
        return self._hunt_descriptor(events)

    def _hunt_descriptor(self, events: list[Event]) -> bool:
        start = 0
        while True:
            at = self._buf.find(DESCRIPTOR_SYNC, start)
            if at < 0:
                keep = 1 if self._buf.endswith(b"\xa5") else 0
                self._consume_junk(len(self._buf) - keep)
                return False
            if len(self._buf) - at < DESCRIPTOR_SIZE:
                self._consume_junk(at)
                return False
            desc = parse_descriptor(self._buf[at:at + DESCRIPTOR_SIZE])
            if desc is None:
                start = at + 1
                continue
            self._consume_junk(at)
            self._buf = self._buf[DESCRIPTOR_SIZE:]
            self._start(desc, events)
            return True

    def _start(self, desc: Descriptor, events: list[Event]) -> None:
        self.stats.descriptors += 1
        events.append(desc)
        self._fold_stream_stats()
        self._stream = None
        if not desc.multi:
            self._single = desc
        elif desc.data_type == Ans.NODE:
            step_q6 = int(self.max_node_step_deg * 64)
            self._stream = _NodeStream(self.lock_nodes, step_q6)
        elif desc.data_type in _CAPSULE_DECODERS:
            self._stream = _CapsuleStream(desc.data_type)
        else:
            events.append(UnsupportedStream(desc.data_type))
            self._skip_stream = True

    def _read_single(self, events: list[Event]) -> bool:
        assert self._single is not None
        if len(self._buf) < self._single.length:
            return False
        body, self._buf = self._buf[:self._single.length], self._buf[self._single.length:]
        events.append(parse_reply(self._single, body))
        self._single = None
        return True

    def _read_stream(self, events: list[Event]) -> bool:
        stream = self._stream
        assert stream is not None
        buf = np.frombuffer(self._buf, dtype=np.uint8)
        pos = self._resume
        while True:
            if not stream.locked:
                lock, undecided = stream.find_lock(buf, pos)
                switched = self._descriptor_in(pos, lock if lock is not None else undecided)
                if switched is not None:
                    return self._switch(switched, pos, events)
                if lock is None:
                    self.stats.junk_bytes += max(undecided - pos, 0)
                    self._buf, self._resume = self._buf[undecided:], 0
                    stream.shift(undecided)
                    return False
                self.stats.junk_bytes += max(lock - pos, 0)
                events.extend(stream.on_lock(lock))
                pos = lock
            pos, failed = self._decode_locked(stream, buf, pos, events)
            if not failed:
                break
            verdict = self._descriptor_at(pos)
            if verdict == "wait":
                break
            if verdict == "yes":
                events.extend(stream.finish(buf, pos))
                return self._switch(pos, pos, events)
            rec = buf[pos:pos + stream.size]
            restart = stream.hunt_from(pos)
            stream.lose_sync(rec, stream.check(rec))
            pos = restart
        keep = max(pos - stream.backtrack, 0)
        self._buf, self._resume = self._buf[keep:], pos - keep
        stream.shift(keep)
        return False

    def _decode_locked(self, stream: _RecordStream, buf: U8, pos: int,
                       events: list[Event]) -> tuple[int, bool]:
        """Accept the valid records from ``pos``: (position after them, whether one failed)."""
        count = (len(buf) - pos) // stream.size
        if count == 0:
            return pos, False
        recs = buf[pos:pos + count * stream.size].reshape(count, stream.size)
        valid = stream.valid(recs)
        good = count if valid.all() else int(np.argmin(valid))
        if good:
            events.extend(stream.accept(buf, pos, good))
            self.stats.records += good
        return pos + good * stream.size, good < count

    def _descriptor_at(self, pos: int) -> str:
        """Is a new descriptor at ``pos`` (a record boundary that failed its check)?"""
        head = self._buf[pos:pos + DESCRIPTOR_SIZE]
        if not DESCRIPTOR_SYNC.startswith(head[:2]):
            return "no"
        if len(head) < DESCRIPTOR_SIZE:
            return "wait"
        return "yes" if parse_descriptor(head) else "no"

    def _descriptor_in(self, start: int, end: int) -> int | None:
        at = self._buf.find(DESCRIPTOR_SYNC, start, end + 2)
        while at >= 0:
            if parse_descriptor(self._buf[at:at + DESCRIPTOR_SIZE]):
                return at
            at = self._buf.find(DESCRIPTOR_SYNC, at + 1, end + 2)
        return None

    def _switch(self, at: int, pos: int, events: list[Event]) -> bool:
        self.stats.junk_bytes += max(at - pos, 0)
        self._buf, self._resume = self._buf[at:], 0
        self._fold_stream_stats()
        self._stream = None
        return True

    def _consume_junk(self, count: int) -> None:
        self._resume = 0
        if count > 0:
            self.stats.junk_bytes += count
            self._buf = self._buf[count:]

    def _fold_stream_stats(self) -> None:
        stream = self._stream
        if stream is None:
            return
        self.stats.resyncs += stream.resyncs
        self.stats.angle_misfits += stream.misfits
        if isinstance(stream, _CapsuleStream):
            self.stats.dropped_capsules += stream.dropped
        else:
            self.stats.dropped_nodes += stream.dropped
        stream.resyncs = stream.misfits = stream.dropped = 0
