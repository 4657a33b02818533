# Vectorised decoders for RPLIDAR measurement records (standard nodes and capsules); pure numpy.
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

U8 = npt.NDArray[np.uint8]
I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]

FULL_TURN_Q6 = 360 << 6
FULL_TURN_Q16 = 360 << 16
#: Quality reported for a capsule sample with a return (capsules carry none; the SDK uses 47).
CAPSULE_QUALITY = 47

NODE_SIZE = 5
LEGACY_SIZE = 84
DENSE_SIZE = 84
ULTRA_SIZE = 132


@dataclass
class DecodedSamples:
    """Samples in device order: angle (deg, clockwise), distance (mm, 0 = no return), quality 0-63,
    ``base_q16``: the un-offset rotor angle (q16 deg, mod 360) used to find revolution starts."""

    angle_deg: F64
    distance_mm: F64
    quality: U8
    base_q16: I64


# ---------------------------------------------------------------- standard 5-byte nodes


def node_check(b0: U8, b1: U8, b2: U8) -> Bools:
    """The node integrity rule: S != !S, C == 1, angle below 360 degrees."""
    bits_ok = (((b0 ^ (b0 >> 1)) & 1) & (b1 & 1)).astype(bool)
    return bits_ok & (node_angle_q6(b1, b2) < FULL_TURN_Q6)


def node_angle_q6(b1: U8, b2: U8) -> I64:
    return (b1 >> 1).astype(np.int64) | (b2.astype(np.int64) << 7)


def decode_nodes(recs: U8) -> tuple[F64, F64, U8, Bools]:
    """Decode an (n, 5) array of nodes: angle deg, distance mm, quality, start-of-revolution."""
    b0 = recs[:, 0]
    angle = node_angle_q6(recs[:, 1], recs[:, 2]) / 64.0
    dist = (recs[:, 3].astype(np.int64) | (recs[:, 4].astype(np.int64) << 8)) / 4.0
    return angle, dist, (b0 >> 2).astype(np.uint8), (b0 & 1).astype(bool)


# ---------------------------------------------------------------- capsules (shared header)


def capsule_check(recs: U8) -> Bools:
    """Sync nibbles 0xA/0x5 and the XOR of bytes 2.. against the split checksum, per row."""
    sync_ok = ((recs[:, 0] >> 4) == 0xA) & ((recs[:, 1] >> 4) == 0x5)
    expected = (recs[:, 0] & 0xF) | ((recs[:, 1] & 0xF) << 4)
    return sync_ok & (np.bitwise_xor.reduce(recs[:, 2:], axis=1) == expected)


def capsule_start_q6(recs: U8) -> I64:
    return (recs[:, 2].astype(np.int64) | (recs[:, 3].astype(np.int64) << 8)) & 0x7FFF


def capsule_sync(recs: U8) -> Bools:
    return (recs[:, 3] & 0x80).astype(bool)


def _u16(recs: U8, first: int, count: int) -> I64:
    words = recs[:, first:first + 2 * count].reshape(len(recs), count, 2).astype(np.int64)
    return words[:, :, 0] | (words[:, :, 1] << 8)


def _angle_span_q8(cur: U8, nxt: U8) -> I64:
    """Δ from a capsule's start angle to its successor's, q8 degrees, +360 on wrap (SDK rule)."""
    prev_q8 = capsule_start_q6(cur) << 2
    next_q8 = capsule_start_q6(nxt) << 2
    return next_q8 - prev_q8 + np.where(prev_q8 > next_q8, 360 << 8, 0)


def _accumulator(cur: U8, inc_q16: I64, per_capsule: int) -> I64:
    """SDK rotor accumulator per sample: start_q8 << 8 plus k increments, shape (K, n)."""
    start_q16 = (capsule_start_q6(cur) << 2) << 8
    k = np.arange(per_capsule, dtype=np.int64)
    return start_q16[:, None] + k[None, :] * inc_q16[:, None]


def _finish(angle_q6: I64, dist_mm: I64, acc: I64) -> DecodedSamples:
    dist = dist_mm.reshape(-1)
    return DecodedSamples(
        angle_deg=np.mod(angle_q6.reshape(-1), FULL_TURN_Q6) / 64.0,
        distance_mm=dist.astype(np.float64),
        quality=np.where(dist > 0, CAPSULE_QUALITY, 0).astype(np.uint8),
        base_q16=np.mod(acc.reshape(-1), FULL_TURN_Q16),
    )


def decode_legacy(cur: U8, nxt: U8) -> DecodedSamples:
    """Express legacy capsules 0x82 (K, 84) with their successors: SDK fixed-point semantics.

    θ_k = (ω_i + k·Δ/32 - dθ_k/8) mod 360 with dθ unsigned 0..63 and k = 0..31.
    """
    cabins = cur[:, 4:84].reshape(len(cur), 16, 5).astype(np.int64)
    w1 = cabins[:, :, 0] | (cabins[:, :, 1] << 8)
    w2 = cabins[:, :, 2] | (cabins[:, :, 3] << 8)
    offs = cabins[:, :, 4]
    dist = np.stack([w1 >> 2, w2 >> 2], axis=2).reshape(len(cur), 32)
    dtheta_q3 = np.stack([(offs & 0xF) | ((w1 & 3) << 4), (offs >> 4) | ((w2 & 3) << 4)],
                         axis=2).reshape(len(cur), 32)
    acc = _accumulator(cur, _angle_span_q8(cur, nxt) << 3, 32)
    angle_q6 = (acc - (dtheta_q3 << 13)) >> 10
    return _finish(angle_q6, dist, acc)


def decode_dense(cur: U8, nxt: U8) -> DecodedSamples:
    """Dense capsules 0x85 (K, 84): 40 u16 mm each, θ_k = ω_i + k·Δ/40, no offset term."""
    dist = _u16(cur, 4, 40)
    acc = _accumulator(cur, (_angle_span_q8(cur, nxt) << 8) // 40, 40)
    return _finish(acc >> 10, dist, acc)


# ---------------------------------------------------------------- ultra capsules 0x84

_VBS_SCALED_BASE = (3328, 1792, 1280, 512, 0)
_VBS_LEVEL = (4, 3, 2, 1, 0)
_VBS_TARGET_BASE = (1 << 14, 1 << 12, 1 << 11, 1 << 9, 0)
_ULTRA_MEAN_OFFSET_Q16 = int(7.5 * 3.1415926535 * (1 << 16) / 180.0)
_ULTRA_OFFSET_BASE_Q16 = int(8 * 3.1415926535 * (1 << 16) / 180)


def vbs_decode(scaled: I64) -> tuple[I64, I64]:
    """Variable-bit-scale decode of 12-bit majors: (value mm, scale level)."""
    conds = [scaled >= base for base in _VBS_SCALED_BASE]
    levels = np.select(conds, list(_VBS_LEVEL), 0).astype(np.int64)
    bases = np.select(conds, list(_VBS_SCALED_BASE), 0).astype(np.int64)
    targets = np.select(conds, list(_VBS_TARGET_BASE), 0).astype(np.int64)
    return targets + ((scaled - bases) << levels), levels


def _signed10(bits: I64) -> I64:
    return np.where(bits >= 512, bits - 1024, bits)


def _ultra_distances(cur: U8, nxt: U8) -> I64:
    combined = _u16(cur, 4, 64)
    words = combined[:, 0::2] | (combined[:, 1::2] << 16)  # (K, 32) u32
    next_first = _u16(nxt, 4, 2)
    next_words = next_first[:, 0] | (next_first[:, 1] << 16)
    major_raw = words & 0xFFF
    major2_raw = np.concatenate([major_raw[:, 1:], (next_words & 0xFFF)[:, None]], axis=1)
    p1 = _signed10((words >> 12) & 0x3FF)
    p2 = _signed10((words >> 22) & 0x3FF)
    major, lvl1 = vbs_decode(major_raw)
    major2, lvl2 = vbs_decode(major2_raw)
    swap = (major == 0) & (major2 != 0)
    base1 = np.where(swap, major2, major)
    lvl1 = np.where(swap, lvl2, lvl1)
    d1 = np.where((p1 == -512) | (p1 == 511), 0, (p1 << lvl1) + base1)
    d2 = np.where((p2 == -512) | (p2 == 511), 0, (p2 << lvl2) + major2)
    dist = np.stack([major, d1, d2], axis=2).reshape(len(cur), 96)
    return np.maximum(dist, 0)


def ultra_offset_q16(dist_mm: I64) -> I64:
    """The SDK's optical angle offset of an ultra sample, q16 degrees (truncated like the SDK)."""
    dist_q2 = dist_mm << 2
    k2 = 98361 // np.maximum(dist_q2, 1)
    rad_q16 = np.where(dist_q2 >= 200,
                       _ULTRA_OFFSET_BASE_Q16 - (k2 << 6) - (k2 * k2 * k2) // 98304,
                       _ULTRA_MEAN_OFFSET_Q16)
    return np.floor((rad_q16 * 180).astype(np.float64) / 3.14159265).astype(np.int64)


def decode_ultra(cur: U8, nxt: U8) -> DecodedSamples:
    """Ultra capsules 0x84 (K, 132): 96 samples, VBS majors plus predictions, step Δ/96."""
    dist = _ultra_distances(cur, nxt)
    acc = _accumulator(cur, (_angle_span_q8(cur, nxt) << 3) // 3, 96)
    angle_q6 = (acc - ultra_offset_q16(dist)) >> 10
    return _finish(angle_q6, dist, acc)
