# Device-side encoders: the bytes an RPLIDAR sends for given samples (emulator, tests, bench).
from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sensors.rplidar import records
from sensors.rplidar.requests import Ans, Descriptor

ArrayLike = npt.ArrayLike

STREAM_DESCRIPTORS: dict[int, Descriptor] = {
    Ans.NODE: Descriptor(records.NODE_SIZE, True, Ans.NODE),
    Ans.CAPSULE: Descriptor(records.LEGACY_SIZE, True, Ans.CAPSULE),
    Ans.DENSE_CAPSULE: Descriptor(records.DENSE_SIZE, True, Ans.DENSE_CAPSULE),
    Ans.ULTRA_CAPSULE: Descriptor(records.ULTRA_SIZE, True, Ans.ULTRA_CAPSULE),
}
SAMPLES_PER_CAPSULE: dict[int, int] = {
    Ans.CAPSULE: 32, Ans.DENSE_CAPSULE: 40, Ans.ULTRA_CAPSULE: 96,
}


def encode_nodes(angle_deg: ArrayLike, distance_mm: ArrayLike, quality: ArrayLike,
                 start: ArrayLike) -> bytes:
    """Standard 5-byte nodes (angle q6, distance q2, quality 0-63, S flag)."""
    angle_q6 = np.mod(np.rint(np.asarray(angle_deg, dtype=np.float64) * 64), 23040).astype(int)
    dist_q2 = np.clip(np.rint(np.asarray(distance_mm, dtype=np.float64) * 4), 0, 0xFFFF)
    dist_q2 = dist_q2.astype(np.int64)
    s = np.asarray(start, dtype=bool).astype(np.int64)
    q = np.clip(np.asarray(quality, dtype=np.int64), 0, 63)
    out = np.empty((len(angle_q6), 5), dtype=np.uint8)
    out[:, 0] = (q << 2) | ((1 - s) << 1) | s
    out[:, 1] = ((angle_q6 & 0x7F) << 1) | 1
    out[:, 2] = angle_q6 >> 7
    out[:, 3] = dist_q2 & 0xFF
    out[:, 4] = dist_q2 >> 8
    return out.tobytes()


def _capsule_header(body: npt.NDArray[np.uint8], start_q6: ArrayLike,
                    sync: ArrayLike) -> npt.NDArray[np.uint8]:
    start = np.asarray(start_q6, dtype=np.int64) & 0x7FFF
    word = start | (np.asarray(sync, dtype=bool).astype(np.int64) << 15)
    out = np.empty((len(body), body.shape[1] + 4), dtype=np.uint8)
    out[:, 2] = word & 0xFF
    out[:, 3] = word >> 8
    out[:, 4:] = body
    chk = np.bitwise_xor.reduce(out[:, 2:], axis=1)
    out[:, 0] = 0xA0 | (chk & 0xF)
    out[:, 1] = 0x50 | (chk >> 4)
    return out


def _u16_bytes(words: npt.NDArray[np.int64]) -> npt.NDArray[np.uint8]:
    return words.astype("<u2").view(np.uint8).reshape(len(words), -1)


def encode_legacy(start_q6: ArrayLike, distance_mm: ArrayLike, dtheta_q3: ArrayLike,
                  sync: ArrayLike) -> bytes:
    """Express legacy capsules: (K,) start angles q6, (K, 32) mm, (K, 32) dθ in 1/8° (0..63)."""
    dist = np.clip(np.rint(np.asarray(distance_mm, dtype=np.float64)), 0, 16383).astype(np.int64)
    dth = np.asarray(dtheta_q3, dtype=np.int64) & 0x3F
    k = len(dist)
    w = (dist << 2) | (dth >> 4)
    w1, w2 = w[:, 0::2], w[:, 1::2]
    offs = (dth[:, 0::2] & 0xF) | ((dth[:, 1::2] & 0xF) << 4)
    cabins = np.empty((k, 16, 5), dtype=np.uint8)
    cabins[:, :, 0:2] = _u16_bytes(w1).reshape(k, 16, 2)
    cabins[:, :, 2:4] = _u16_bytes(w2).reshape(k, 16, 2)
    cabins[:, :, 4] = offs
    return _capsule_header(cabins.reshape(k, 80), start_q6, sync).tobytes()


def encode_dense(start_q6: ArrayLike, distance_mm: ArrayLike, sync: ArrayLike) -> bytes:
    """Dense capsules: (K,) start angles q6 and (K, 40) distances in mm."""
    dist = np.clip(np.rint(np.asarray(distance_mm, dtype=np.float64)), 0, 0xFFFF).astype(np.int64)
    return _capsule_header(_u16_bytes(dist), start_q6, sync).tobytes()


def vbs_encode(distance_mm: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """Inverse of :func:`records.vbs_decode` (rounding down within a scale level)."""
    d = np.clip(distance_mm, 0, 16384 + (767 << 4))
    return np.select(
        [d >= 16384, d >= 4096, d >= 2048, d >= 512],
        [3328 + ((d - 16384) >> 4), 1792 + ((d - 4096) >> 3), 1280 + ((d - 2048) >> 2),
         512 + ((d - 512) >> 1)],
        d,
    ).astype(np.int64)


def _prediction(target: npt.NDArray[np.int64], base: npt.NDArray[np.int64],
                level: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    p = np.rint((target - base) / (1 << level)).astype(np.int64)
    p = np.clip(p, -511, 510)
    return np.where(target == 0, -512, p)


def encode_ultra(start_q6: ArrayLike, distance_mm: ArrayLike, sync: ArrayLike,
                 next_first_mm: int = 0) -> bytes:
    """Ultra capsules: (K,) start angles and (K, 96) mm; ``next_first_mm`` is the distance of
    the first sample of the capsule after the last one (its major feeds the last prediction)."""
    dist = np.clip(np.rint(np.asarray(distance_mm, dtype=np.float64)), 0, None).astype(np.int64)
    k = len(dist)
    triples = dist.reshape(k * 32, 3)
    majors = vbs_encode(np.concatenate([triples[:, 0], [next_first_mm]]))
    major_dec, lvl = records.vbs_decode(majors)
    m1, l1, m2, l2 = major_dec[:-1], lvl[:-1], major_dec[1:], lvl[1:]
    swap = (m1 == 0) & (m2 != 0)
    p1 = _prediction(triples[:, 1], np.where(swap, m2, m1), np.where(swap, l2, l1))
    p2 = _prediction(triples[:, 2], m2, l2)
    words = majors[:-1] | ((p1 & 0x3FF) << 12) | ((p2 & 0x3FF) << 22)
    body = words.astype("<u4").view(np.uint8).reshape(k, 128)
    return _capsule_header(body, start_q6, sync).tobytes()
