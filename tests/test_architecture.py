# The layer contract of docs/architecture.md (import-linter over the real tree), and the tests' own
# layout: helpers live in tests/support, conftest.py only provides fixtures.
from __future__ import annotations

import ast
import subprocess
import sys
import tomllib
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
    project = tomllib.loads((REPO / "pyproject.toml").read_text())
    for name in project["tool"]["importlinter"]["root_packages"]:
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


def imported_names(source: str) -> list[tuple[int, str]]:
    """(line, dotted name) for every module or name an import statement names, in functions
    too: ``from a.b import c`` names ``a.b`` and ``a.b.c``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = "." * node.level + (node.module or "")
            found.append((node.lineno, base))
            found += [(node.lineno, f"{base}.{alias.name}".lstrip(".")) for alias in node.names]
    return found


def conftest_imports(source: str) -> list[int]:
    """Lines importing a ``conftest`` module (``from tests.conftest import x``,
    ``from .conftest import x``, ``from tests import conftest``, ``import conftest``...)."""
    return sorted({line for line, name in imported_names(source)
                   if "conftest" in name.split(".")})


def imports_of_test_modules(source: str) -> list[int]:
    """Lines importing a test module or a test of one (``from tests.test_x import helper``,
    ``from tests import test_x``): pytest would also collect the tests it brings along."""
    return sorted({line for line, name in imported_names(source)
                   if (name.startswith(("tests.", ".", "test_"))  # the tests' own modules
                       and any(part.startswith("test_") for part in name.split(".")))})


def test_no_test_module_imports_conftest() -> None:
    """conftest.py provides fixtures only: a helper a test imports lives in tests/support."""
    offenders = [f"{path.relative_to(REPO)}:{line}" for path in python_files_of_the_tests()
                 for line in conftest_imports(path.read_text())]
    assert offenders == [], "import these from tests/support instead"


def test_no_test_module_imports_another() -> None:
    """A helper two test modules share lives in tests/support, not in one of them."""
    offenders = [f"{path.relative_to(REPO)}:{line}" for path in python_files_of_the_tests()
                 for line in imports_of_test_modules(path.read_text())]
    assert offenders == [], "move what they share to tests/support"


def test_a_conftest_import_is_found_in_every_spelling() -> None:
    source = ("from tests.conftest import wait_for\nfrom .conftest import Robot\n"
              "from tests import conftest\nimport conftest\n"
              "def f() -> None:\n    from conftest import close_to\n"
              "from tests.support.wait import wait_for  # conftest\n")
    assert conftest_imports(source) == [1, 2, 3, 4, 6]


def test_an_import_of_a_test_module_is_found() -> None:
    source = ("from tests.test_rosbridge_server import connect\nfrom tests import test_x\n"
              "import tests.test_y\nfrom tests.support.rosbridge import connect\n"
              "def f() -> None:\n    from .test_z import helper\n"
              "from aiohttp.test_utils import TestServer\n")
    assert imports_of_test_modules(source) == [1, 2, 3, 6]


def test_every_support_module_says_what_it_is_for() -> None:
    """Each module of tests/support opens (after a shebang) with a one-line purpose comment."""
    for path in sorted((TESTS / "support").rglob("*.py")):
        lines = path.read_text().splitlines()
        if lines and lines[0].startswith("#!"):
            lines = lines[1:]
        assert lines and lines[0].startswith("# ") and len(lines[0]) > 10, path


#: modules a daemon with every component off must not load at start (slow imports, memory)
HEAVY_AT_START = ("scipy", "rosbags", "cyclonedds", "mcap_ros2")


def test_the_daemon_and_its_cli_start_without_the_heavy_libraries() -> None:
    code = ("import sys, daemon.cli, daemon.app, daemon.registry\n"
            f"print(' '.join(m for m in {HEAVY_AT_START!r} if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            cwd=REPO, check=True).stdout.split()
    assert not loaded, f"imported at start: {loaded}; import them where they are used"
