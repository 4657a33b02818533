# Seeded noise for the simulated robot: lidar range noise and dropouts, encoder noise, slip.
from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NoiseConfig:
    """What noise the world injects; ``enabled=False`` turns all of it off (exact runs).

    ``lidar_sigma`` is the standard deviation of each range return (m). ``odom_sigma`` is the
    standard deviation of each wheel's encoder reading about the wheel's true travel (m),
    drawn afresh on every physics step in which the wheel turns. ``wheel_slip`` is the
    fraction of wheel travel lost at the ground (0 = none), so the robot moves less than its
    encoders say. ``lidar_dropout`` is the probability that a ray's return goes missing
    (reported as ``inf``, no return), drawn independently per ray. ``seed`` seeds every
    stream.
    """

    enabled: bool = True
    lidar_sigma: float = 0.02
    odom_sigma: float = 0.005
    wheel_slip: float = 0.0
    seed: int = 1
    lidar_dropout: float = 0.0

    def __post_init__(self) -> None:
        if self.lidar_sigma < 0 or self.odom_sigma < 0:
            raise ValueError("noise sigmas must be >= 0")
        if not 0 <= self.wheel_slip < 1:
            raise ValueError(f"wheel_slip must be in [0, 1), got {self.wheel_slip}")
        if not 0 <= self.lidar_dropout < 1:
            raise ValueError(f"lidar_dropout must be in [0, 1), got {self.lidar_dropout}")

    @property
    def slip(self) -> float:
        """The slip actually applied (0 when noise is off)."""
        return self.wheel_slip if self.enabled else 0.0


Draw = Callable[[np.random.Generator, int], np.ndarray]


def _standard_normal(generator: np.random.Generator, count: int) -> np.ndarray:
    return generator.standard_normal(count)


def _uniform(generator: np.random.Generator, count: int) -> np.ndarray:
    return generator.random(count)


class GaussianStream:
    """Standard normal draws from one seeded generator, fetched in blocks (cheap per draw).

    The sequence depends only on the seed and on how many values were taken, so two streams
    with the same seed give the same values whatever the block boundaries are. ``draw``
    swaps the distribution (:class:`UniformStream` draws uniformly from [0, 1)).
    """

    def __init__(self, seed_sequence: np.random.SeedSequence, block: int = 4096,
                 draw: Draw = _standard_normal) -> None:
        self._generator = np.random.Generator(np.random.PCG64(seed_sequence))
        self._draw = draw
        self._block = block
        self._buffer = np.empty(0)
        self._next = 0
        self._lock = threading.Lock()

    def take(self, count: int) -> np.ndarray:
        """The next ``count`` standard normal values."""
        with self._lock:
            if self._next + count > len(self._buffer):
                rest = self._buffer[self._next:]
                fresh = self._draw(self._generator, max(self._block, count))
                self._buffer, self._next = np.concatenate([rest, fresh]), 0
            values = self._buffer[self._next:self._next + count]
            self._next += count
            return values

    def one(self) -> float:
        return float(self.take(1)[0])


class UniformStream(GaussianStream):
    """Uniform draws from [0, 1), blockwise like :class:`GaussianStream`."""

    def __init__(self, seed_sequence: np.random.SeedSequence, block: int = 4096) -> None:
        super().__init__(seed_sequence, block, _uniform)


class Noise:
    """The noise sources of one simulated robot, each on its own seeded stream.

    Separate streams keep the runs reproducible when the lidar is sampled at a different
    time or rate than the physics: encoder noise never depends on how many scans were taken.
    The dropout stream is the seed's third child, so adding it left the first two (and every
    run without dropouts) exactly as they were.
    """

    def __init__(self, config: NoiseConfig) -> None:
        self.config = config
        lidar_seq, odom_seq, dropout_seq = np.random.SeedSequence(config.seed).spawn(3)
        self._lidar = GaussianStream(lidar_seq)
        self._odom = GaussianStream(odom_seq)
        self._dropout = UniformStream(dropout_seq)

    @property
    def lidar_on(self) -> bool:
        return self.config.enabled and self.config.lidar_sigma > 0

    @property
    def dropout_on(self) -> bool:
        return self.config.enabled and self.config.lidar_dropout > 0

    @property
    def odom_on(self) -> bool:
        return self.config.enabled and self.config.odom_sigma > 0

    def lidar(self, ranges: np.ndarray) -> np.ndarray:
        """``ranges`` plus Gaussian noise on every return, less the dropped returns (``inf``);
        ``inf`` (no return) stays ``inf``. One dropout draw per ray, whatever it hit."""
        if self.lidar_on:
            noisy = ranges + self._lidar.take(len(ranges)) * self.config.lidar_sigma
            ranges = np.maximum(noisy, 0.0)
        if self.dropout_on:
            dropped = self._dropout.take(len(ranges)) < self.config.lidar_dropout
            ranges = np.where(dropped, np.inf, ranges)
        return ranges

    def encoder_offsets(self) -> tuple[float, float]:
        """Fresh encoder reading errors (m) for the left and right wheel."""
        if not self.odom_on:
            return 0.0, 0.0
        left, right = self._odom.take(2)
        sigma = self.config.odom_sigma
        return float(left) * sigma, float(right) * sigma
