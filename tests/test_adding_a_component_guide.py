# docs/adding-a-component.md's example, built from the page's own code and run in a daemon.
from __future__ import annotations

import importlib
import re
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import aiohttp
import pytest

import daemon.app
import daemon.components
import daemon.config
from daemon.registry import COMPONENTS
from tests.support.in_process_daemon import in_process_daemon
from tests.support.paths import REPO
from tests.support.wait import eventually

GUIDE = REPO / "docs" / "adding-a-component.md"
PACKAGE = "daemon/components/odometer"


def guide_files() -> dict[str, str]:
    """The page's ``python`` blocks, each by the file named in the paragraph before it."""
    files: dict[str, str] = {}
    text = GUIDE.read_text()
    for match in re.finditer(r"```python\n(.*?)```", text, flags=re.S):
        before = text[:match.start()].rstrip().rsplit("\n\n", 1)[-1]
        named = re.findall(rf"`({PACKAGE}/\w+\.py)`", before)
        if named:
            files[named[-1]] = match.group(1)
    return files


@pytest.fixture
def odometer(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[ModuleType]:
    """The guide's package where the kernel looks for components, and its row in the table."""
    files = guide_files()
    assert set(files) == {f"{PACKAGE}/settings.py", f"{PACKAGE}/component.py"}, files
    home = tmp_path / "extra"
    (home / "odometer").mkdir(parents=True)
    (home / "odometer" / "__init__.py").write_text("# The odometer component: distance driven.\n")
    for path, code in files.items():
        (home / "odometer" / Path(path).name).write_text(code)
    monkeypatch.setattr(daemon.components, "__path__", [*daemon.components.__path__, str(home)])
    module = importlib.import_module("daemon.components.odometer.component")
    rows = (*COMPONENTS[:-1], module.COMPONENT, COMPONENTS[-1])  # before the HTTP server
    monkeypatch.setattr(daemon.app, "COMPONENTS", rows)
    monkeypatch.setattr(daemon.config, "COMPONENTS", rows)
    settings = module.COMPONENT.settings
    monkeypatch.setitem(daemon.config.SETTINGS, "odometer", settings)
    monkeypatch.setitem(daemon.config.SECTIONS, "odometer", settings.OPTIONS)
    try:
        yield module
    finally:
        for name in [n for n in sys.modules if n.startswith("daemon.components.odometer")]:
            del sys.modules[name]


async def test_the_guides_odometer_runs_as_the_guide_says(tmp_path: Path,
                                                          odometer: ModuleType) -> None:
    async with in_process_daemon(tmp_path, "[odometer]\npublish_rate = 5.0\n") as robot, \
            aiohttp.ClientSession() as session:
        async with session.post(robot.http_url + "/api/cmd_vel",
                                json={"linear": {"x": 0.3}}) as answer:
            assert answer.status == 200, await answer.text()

        async def metres() -> float:
            async with session.get(robot.http_url + "/api/odometer") as answer:
                assert answer.status == 200
                return float((await answer.json())["metres"])

        assert await eventually(metres, "the odometer counting the drive") > 0.0
        async with session.get(robot.http_url + "/api/health") as answer:
            health = (await answer.json())["components"]["odometer"]
        assert health["status"] == "ok" and "metres" in health
        assert robot.ctx.topics.owner("/odometer") == "odometer"


def test_the_guides_section_is_checked_like_every_other(odometer: ModuleType,
                                                        tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[odometer]\npublish_rate = 500.0\n")
    with pytest.raises(daemon.config.ConfigError, match=r"\[odometer\] publish_rate"):
        daemon.config.load_config(bad, env={})
