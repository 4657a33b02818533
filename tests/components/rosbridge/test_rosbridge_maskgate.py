# MaskGate: a frame without the mask bit is refused, however the bytes arrive.
from __future__ import annotations

from typing import Any

import pytest

from daemon.components.rosbridge.maskgate import MaskGate


def frame(payload: bytes, masked: bool = True) -> bytes:
    size = len(payload)
    mask = 0x80 if masked else 0
    head = bytes([0x81, mask | size]) if size < 126 else \
        bytes([0x81, mask | 126]) + size.to_bytes(2, "big") if size < 65536 else \
        bytes([0x81, mask | 127]) + size.to_bytes(8, "big")
    return head + (b"\x01\x02\x03\x04" if masked else b"") + payload


class Parser:
    def __init__(self) -> None:
        self.fed: list[bytes] = []

    def feed_data(self, data: bytes) -> tuple[bool, bytes]:
        self.fed.append(data)
        return False, b""

    def feed_eof(self) -> None:
        pass


def gate() -> tuple[MaskGate, Parser, list[BaseException]]:
    parser, refused = Parser(), []
    refuse: Any = refused.append
    return MaskGate(parser, refuse), parser, refused


@pytest.mark.parametrize("size", [0, 5, 125, 126, 200, 65535, 65536])
def test_whole_masked_frames_reach_the_parser(size: int) -> None:
    g, parser, refused = gate()
    data = frame(b"x" * size)
    g.feed_data(data)
    g.feed_data(data + data)
    assert parser.fed == [data, data + data] and not refused


@pytest.mark.parametrize("size", [5, 150, 70000])
def test_an_unmasked_frame_is_refused_whole_or_in_pieces(size: int) -> None:
    for cut in (None, 1, 3, 9):
        g, parser, refused = gate()
        data = frame(b"y" * size, masked=False)
        pieces = [data] if cut is None else [data[:cut], data[cut:]]
        for piece in pieces:
            g.feed_data(piece)
        # a piece before the whole header may reach the parser; from the piece that
        # completes the header (and shows the missing mask bit) on, nothing does
        header = 2 if size < 126 else 4 if size < 65536 else 10
        assert refused and parser.fed == ([data[:cut]] if cut is not None and cut < header
                                          else [])
        assert g.feed_data(frame(b"z")) == (True, b"")  # nothing more after a refusal


def test_an_unmasked_frame_after_a_masked_one_is_refused() -> None:
    g, parser, refused = gate()
    good = frame(b"a" * 150)
    g.feed_data(good)
    g.feed_data(good[:20])
    g.feed_data(good[20:] + frame(b"b", masked=False))
    assert refused and parser.fed == [good, good[:20]]
