# Run metrics of the simulated robot: collisions, path, speed, smoothness; CSV at a fixed rate.
from __future__ import annotations

import math
from pathlib import Path
from typing import IO, Any

CSV_COLUMNS = ("run", "t", "x", "y", "theta", "v", "w", "path_length", "collisions",
               "mean_speed", "rms_lin_acc", "rms_ang_acc", "rms_lin_jerk", "rms_ang_jerk")


class _RmsDerivatives:
    """Running RMS of the first and second time derivative of one sampled velocity."""

    def __init__(self) -> None:
        self.velocity = 0.0
        self.acceleration = 0.0
        self.sum_acc2 = 0.0
        self.sum_jerk2 = 0.0
        self.samples = 0

    def add(self, velocity: float, dt: float) -> None:
        acceleration = (velocity - self.velocity) / dt
        jerk = (acceleration - self.acceleration) / dt
        self.sum_acc2 += acceleration * acceleration
        self.sum_jerk2 += jerk * jerk
        self.samples += 1
        self.velocity, self.acceleration = velocity, acceleration

    @property
    def rms_acceleration(self) -> float:
        return math.sqrt(self.sum_acc2 / self.samples) if self.samples else 0.0

    @property
    def rms_jerk(self) -> float:
        return math.sqrt(self.sum_jerk2 / self.samples) if self.samples else 0.0


class RunMetrics:
    """Accumulates one run's metrics from the true motion, one physics step at a time.

    Acceleration and jerk are finite differences of the true linear and angular velocity
    over the physics step (the robot starts each run at rest). With ``csv_path`` set, one
    row of :data:`CSV_COLUMNS` is written every ``1/rate`` seconds of simulated time, at the
    first physics step at or after each multiple of the period (rows
    are fixed-precision text, so identical runs give identical files); a reset starts a new
    run number in the same file.
    """

    def __init__(self, csv_path: str | Path | None = None, rate: float = 10.0) -> None:
        if rate <= 0:
            raise ValueError(f"metrics rate must be > 0, got {rate}")
        self.rate = rate
        self.run = 0
        self._file: IO[str] | None = None
        if csv_path:
            self._file = open(csv_path, "w", encoding="ascii", newline="")  # noqa: SIM115
            self._file.write(",".join(CSV_COLUMNS) + "\n")
        self._start_run()

    def _start_run(self) -> None:
        self.run += 1
        self.elapsed = 0.0
        self.path_length = 0.0
        self.collisions = 0
        self.max_speed = 0.0
        self._steps = 0
        self._rows = 0
        self._linear = _RmsDerivatives()
        self._angular = _RmsDerivatives()
        self._last: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def reset(self) -> None:
        """Start a new run (the robot is at rest again)."""
        self.flush()
        self._start_run()

    def record(self, dt: float, x: float, y: float, theta: float, v: float, w: float,
               travelled: float, collisions: int) -> None:
        """Add one physics step: the pose after it, its velocities and translation."""
        self._steps += 1
        self.elapsed = self._steps * dt
        self.path_length += travelled
        self.collisions = collisions
        self.max_speed = max(self.max_speed, abs(v))
        self._linear.add(v, dt)
        self._angular.add(w, dt)
        self._last = (x, y, theta, v, w)
        if self._file is not None:
            self._write_due_rows()

    def _write_due_rows(self) -> None:
        # one row at the first step at or after each multiple of 1/rate (1e-9: float slack)
        if (self._rows + 1) / self.rate > self.elapsed + 1e-9:
            return
        self._write_row()
        self._rows = max(self._rows + 1, math.floor((self.elapsed + 1e-9) * self.rate))

    def _write_row(self) -> None:
        assert self._file is not None
        x, y, theta, v, w = self._last
        values = (self.elapsed, x, y, theta, v, w, self.path_length)
        smooth = (self.mean_speed, self._linear.rms_acceleration, self._angular.rms_acceleration,
                  self._linear.rms_jerk, self._angular.rms_jerk)
        text = ",".join(f"{value:.6f}" for value in values)
        text += f",{self.collisions}," + ",".join(f"{value:.6f}" for value in smooth)
        self._file.write(f"{self.run},{text}\n")

    @property
    def mean_speed(self) -> float:
        return self.path_length / self.elapsed if self.elapsed > 0 else 0.0

    def summary(self) -> dict[str, Any]:
        """The run so far, for ``GET /api/sim/metrics``."""
        return {
            "run": self.run,
            "elapsed_s": round(self.elapsed, 6),
            "collisions": self.collisions,
            "path_length_m": round(self.path_length, 6),
            "mean_speed_m_s": round(self.mean_speed, 6),
            "max_speed_m_s": round(self.max_speed, 6),
            "rms_linear_acceleration_m_s2": round(self._linear.rms_acceleration, 6),
            "rms_angular_acceleration_rad_s2": round(self._angular.rms_acceleration, 6),
            "rms_linear_jerk_m_s3": round(self._linear.rms_jerk, 6),
            "rms_angular_jerk_rad_s3": round(self._angular.rms_jerk, 6),
            "steps": self._steps,
        }

    def flush(self) -> None:
        if self._file is not None:
            self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
