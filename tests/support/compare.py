# Comparing measured numbers: within a tolerance of what was expected.
from __future__ import annotations

from collections.abc import Sequence


def close_to(actual: float | Sequence[float], expected: float | Sequence[float],
             tol: float) -> bool:
    """Each value of ``actual`` within ``tol`` of ``expected`` (numbers or equal-length pairs)."""
    if isinstance(actual, int | float) and isinstance(expected, int | float):
        return abs(actual - expected) <= tol
    assert not isinstance(actual, int | float) and not isinstance(expected, int | float)
    return all(abs(a - e) <= tol for a, e in zip(actual, expected, strict=True))
