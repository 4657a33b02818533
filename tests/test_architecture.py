# The layer contract of docs/architecture.md (import-linter over the real tree), and the tests' own
# layout: helpers live in tests/support, conftest.py only provides fixtures.
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from tests.support.paths import REPO

TESTS = REPO / "tests"


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


def python_files_of_the_tests() -> list[Path]:
    """Every Python file of the test tree (not the npm packages of the JavaScript clients)."""
    return sorted(p for p in TESTS.rglob("*.py") if "node_modules" not in p.parts)


def conftest_imports(source: str) -> list[int]:
    """Line numbers of the imports of a ``conftest`` module (``from tests.conftest import x``,
    ``from .conftest import x``, ``from tests import conftest``, ``import conftest``...)."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            names = [node.module or "", *(alias.name for alias in node.names)]
        else:
            continue
        if any("conftest" in name.split(".") for name in names):
            lines.append(node.lineno)
    return lines


def test_no_test_module_imports_conftest() -> None:
    """conftest.py provides fixtures only: a helper a test imports lives in tests/support."""
    offenders = [f"{path.relative_to(REPO)}:{line}" for path in python_files_of_the_tests()
                 for line in conftest_imports(path.read_text())]
    assert offenders == [], "import these from tests/support instead"


def test_a_conftest_import_is_found_in_every_spelling() -> None:
    source = ("from tests.conftest import wait_for\nfrom .conftest import Robot\n"
              "from tests import conftest\nimport conftest\n"
              "def f() -> None:\n    from conftest import close_to\n"
              "from tests.support.wait import wait_for  # conftest\n")
    assert conftest_imports(source) == [1, 2, 3, 4, 6]


def test_every_support_module_says_what_it_is_for() -> None:
    """Each module of tests/support opens (after a shebang) with a one-line purpose comment."""
    for path in sorted((TESTS / "support").rglob("*.py")):
        lines = path.read_text().splitlines()
        if lines and lines[0].startswith("#!"):
            lines = lines[1:]
        assert lines and lines[0].startswith("# ") and len(lines[0]) > 10, path
