# Quadrature encoder signals (pure): edge count -> pin levels and back, for drivers and emulators.
from __future__ import annotations

#: (A, B) levels of a pulled-up encoder at each count modulo 4: rest is both high and, counting
#: up, A falls first (gpiozero's clockwise).
LEVELS = ((1, 1), (0, 1), (0, 0), (1, 0))
_STATES = [(a << 1) | b for a, b in LEVELS]
_UP = {(_STATES[i], _STATES[(i + 1) % 4]) for i in range(4)}
_DOWN = {(new, old) for old, new in _UP}


def quadrature_levels(count: int) -> tuple[int, int]:
    """Pin levels (A, B) of a quadrature encoder at edge count ``count``."""
    return LEVELS[count % 4]


class QuadratureDecoder:
    """Counts a quadrature encoder from its A and B levels, one edge at a time (x4 decoding).

    Counting up, the (A, B) levels go 11 -> 01 -> 00 -> 10 -> 11 (A falls first). A jump that
    changes both levels at once (a missed edge) is counted in ``errors``, not guessed.
    """

    def __init__(self) -> None:
        self.count = 0
        self.errors = 0
        self.state = 3

    def reset_levels(self, a: int, b: int) -> None:
        """Take the current levels as the new reference without counting (after a reconnect)."""
        self.state = (a << 1) | b

    def update(self, a: int, b: int) -> None:
        new = (a << 1) | b
        step = (self.state, new)
        if step in _UP:
            self.count += 1
        elif step in _DOWN:
            self.count -= 1
        elif new != self.state:
            self.errors += 1
        self.state = new
