# The console bench's traffic replay drives a real `arbiterd run --sim` the way the page does,
# in windows that alternate with no client at all.
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.paths import REPO
from tests.support.wait import wait_for


def test_replayed_console_alternates_idle_and_driving_windows(tmp_path: Path) -> None:
    with DaemonSubprocess(tmp_path, args=("--sim",)) as daemon:
        _, before = daemon.get("/api/latency")
        result = subprocess.run(
            [sys.executable, "-m", "daemon.bench.console", "--http", daemon.base_url,
             "--ws", f"ws://127.0.0.1:{daemon.ws_port}/", "--seconds", "1", "--cycles", "2"],
            cwd=REPO, capture_output=True, text=True, timeout=60, check=False)
        assert result.returncode == 0, result.stderr
        out = json.loads(result.stdout.strip().splitlines()[-1])
        # the newest command wins, so under load a few may be superseded by the next
        wait_for(lambda: daemon.get("/api/latency")[1]["commands"] - before["commands"]
                 >= 0.8 * out["commands"], "the replayed commands applied", within_s=5)
        _, health = daemon.get("/api/health")
    idle, console = out["windows"]["idle"], out["windows"]["console"]
    assert len(idle) == len(console) == 2
    assert idle[0][1] <= console[0][0] < console[0][1] <= idle[1][0]
    assert out["commands"] >= 30 and out["polls"] >= 8
    assert out["messages"] >= 40  # /odom alone is 20 Hz
    assert health["components"]["rosbridge"]["connections"] == 2  # one per console window
