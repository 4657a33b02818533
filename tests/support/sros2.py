# Test harness: an SROS2-layout keystore made by the openssl recipe docs/ros2.md shows.
from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

from tests.support.paths import REPO

MARKER = "<!-- keystore-recipe -->"


def recipe() -> str:
    """The ```sh block after the marker in docs/ros2.md (so the documented steps are run)."""
    text = (REPO / "docs" / "ros2.md").read_text()
    found = re.search(re.escape(MARKER) + r"\s*```sh\n(.*?)```", text, re.S)
    assert found, f"docs/ros2.md has no ```sh block after {MARKER}"
    return found[1]


def openssl_missing() -> str | None:
    return None if shutil.which("openssl") else "no openssl(1) to make a keystore"


def make_keystore(root: Path, *names: str) -> Path:
    """A keystore at ``root`` with an enclave per name; returns ``root / "enclaves"``."""
    result = subprocess.run(["sh", "-s", "--", str(root), *names], input=recipe(), text=True,
                            capture_output=True, timeout=60, check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    return root / "enclaves"
