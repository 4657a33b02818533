# The layer contract of docs/architecture.md, enforced by import-linter over the real tree.
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def lint_imports(*args: str, cwd: Path = REPO) -> subprocess.CompletedProcess[str]:
    tool = Path(sys.executable).with_name("lint-imports")
    return subprocess.run([str(tool), "--no-cache", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=120, check=False)


def test_import_contracts_hold() -> None:
    result = lint_imports()
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


def test_a_driver_importing_the_daemon_breaks_the_contract(tmp_path: Path) -> None:
    """The contract really bites: a copy of the tree with one wrong import fails it."""
    for name in ("base", "daemon", "drivers", "sensors", "sim"):
        subprocess.run(["cp", "-r", str(REPO / name), str(tmp_path / name)], check=True)
    (tmp_path / "pyproject.toml").write_text((REPO / "pyproject.toml").read_text())
    mock = tmp_path / "drivers" / "mock.py"
    mock.write_text(mock.read_text() + "\nfrom daemon.config import Config  # noqa\n")
    result = lint_imports(cwd=tmp_path)
    assert result.returncode != 0
    assert "drivers.mock -> daemon.config" in result.stdout
