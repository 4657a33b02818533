# The console bench's traffic replay drives a real `arbiterd run --sim` the way the page does.
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.daemon_proc import REPO, DaemonProcess, wait_for


def test_replayed_console_drives_and_reads_telemetry(tmp_path: Path) -> None:
    with DaemonProcess(tmp_path, args=("--sim",)) as daemon:
        _, before = daemon.get("/api/latency")
        result = subprocess.run(
            [sys.executable, "-m", "daemon.bench.console", "--http", daemon.base_url,
             "--ws", f"ws://127.0.0.1:{daemon.ws_port}/", "--seconds", "1"],
            cwd=REPO, capture_output=True, text=True, timeout=60, check=False)
        assert result.returncode == 0, result.stderr
        counts = json.loads(result.stdout.strip().splitlines()[-1])
        # the newest command wins, so under load a few may be superseded by the next
        wait_for(lambda: daemon.get("/api/latency")[1]["commands"] - before["commands"]
                 >= 0.8 * counts["commands"], 5, "the replayed commands applied")
    assert counts["commands"] >= 15 and counts["polls"] >= 4
    assert counts["messages"] >= 20  # /odom alone is 20 Hz
