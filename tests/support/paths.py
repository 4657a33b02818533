# Where things are: the root of the repository the tests run the daemon and scripts from.
from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
