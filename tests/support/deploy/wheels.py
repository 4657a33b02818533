# Builds, once per test run (shared by pytest-xdist's workers), the arbiterd wheel and an offline
# wheelhouse of its dependencies.
from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.support.paths import REPO

SOURCE_DIRS = ("base", "daemon", "drivers", "sensors", "sim")


@dataclass(frozen=True)
class Wheels:
    wheel: Path  # arbiterd built from this checkout
    wheelhouse: Path  # that wheel, every runtime dependency, pip, setuptools and wheel, for
    # pip --no-index (installing the wheel or building the source tree offline)
    broken_wheel: Path  # a release whose daemon dies at start-up


_cache: dict[str, Wheels] = {}


def pip(*args: str, env: dict[str, str] | None = None) -> None:
    cmd = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q", *args]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False,
                            env=None if env is None else {**os.environ, **env})
    assert result.returncode == 0, f"{' '.join(cmd)} failed:\n{result.stderr}"


def build_wheel(source: Path, dest: Path) -> Path:
    dest.mkdir(parents=True, exist_ok=True)
    before = set(dest.glob("arbiterd-*.whl"))
    pip("wheel", "--no-deps", "-w", str(dest), str(source))
    (built,) = set(dest.glob("arbiterd-*.whl")) - before
    return built


def broken_source(work: Path) -> Path:
    """A copy of the package sources whose daemon raises on import: the bad release."""
    copy = work / "broken-src"
    copy.mkdir(parents=True, exist_ok=True)
    shutil.copy(REPO / "pyproject.toml", copy)
    for name in ("README.md",):
        if (REPO / name).exists():
            shutil.copy(REPO / name, copy)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in SOURCE_DIRS:
        shutil.copytree(REPO / name, copy / name, ignore=ignore)
    init = copy / "daemon" / "__init__.py"
    init.write_text(init.read_text() + '\nraise SystemExit("deliberately broken release")\n')
    return copy


def shared_dir(factory: pytest.TempPathFactory) -> Path:
    """A folder every xdist worker of this run sees (the run's base temp without them)."""
    base = factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@contextlib.contextmanager
def exclusive(folder: Path) -> Iterator[None]:
    """Holds folder's lock file: one process at a time builds what is in it."""
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


def wheels(factory: pytest.TempPathFactory) -> Wheels:
    """The run's wheels, built by the first process to ask for them."""
    if "wheels" in _cache:
        return _cache["wheels"]
    work = shared_dir(factory) / "arbiterd-wheels"
    with exclusive(work):
        if not (work / "built").exists():
            wheel = build_wheel(REPO, work / "good")
            house = work / "wheelhouse"
            house.mkdir()
            shutil.copy(wheel, house)
            pip("wheel", "-w", str(house), str(wheel))
            # what a release venv bootstraps with, and what an offline source build needs
            pip("download", "-d", str(house), "pip", "setuptools>=77", "wheel")
            build_wheel(broken_source(work), work / "broken")
            (work / "built").touch()
    (wheel,) = (work / "good").glob("arbiterd-*.whl")
    (broken,) = (work / "broken").glob("arbiterd-*.whl")
    _cache["wheels"] = Wheels(wheel=wheel, wheelhouse=work / "wheelhouse", broken_wheel=broken)
    return _cache["wheels"]


def add_ros2_extra(built: Wheels) -> None:
    """Adds the ros2 extra's wheels (the Cyclone DDS binding, built against Debian's library
    the way ./install.sh dev builds it) to the wheelhouse, once."""
    with exclusive(built.wheelhouse.parent):
        marker = built.wheelhouse.parent / "ros2-added"
        if not marker.exists():
            pip("wheel", "-w", str(built.wheelhouse), f"{built.wheel}[ros2]",
                env={"CYCLONEDDS_HOME": str(Path(sys.prefix) / "cyclonedds-home")})
            marker.touch()
