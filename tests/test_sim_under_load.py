# The default simulated robot stays steady while every core of the machine is busy (issue 40).
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.wait import wait_for

#: how long the machine is loaded (s): bounded, the busy loops end themselves too
LOAD_S = 20.0
BUSY_LOOP = ("import time\nend = time.monotonic() + {s}\n"
             "while time.monotonic() < end:\n    pass\n")


def test_run_sim_holds_without_a_driver_fault_beside_busy_loops_on_every_core(
        tmp_path: Path) -> None:
    daemon = DaemonSubprocess(tmp_path, args=("--sim",), use_mock_log=False).start()
    busy: list[subprocess.Popen[bytes]] = []
    try:
        wait_for(lambda: daemon.get("/api/health")[1]["components"]["control"]["status"]
                 == "ok", "the simulated robot's control loop", within_s=30)
        script = BUSY_LOOP.format(s=LOAD_S + 5)
        busy = [subprocess.Popen([sys.executable, "-c", script])
                for _ in range(2 * (os.cpu_count() or 1))]
        end = time.monotonic() + LOAD_S
        while time.monotonic() < end:  # the load's duration, not a wait for a state
            time.sleep(1.0)
            assert "driver fault" not in daemon.log(), daemon.log()[-3000:]
        _, health = daemon.get("/api/health", timeout=10.0)
        assert health["components"]["control"]["faults"] == 0, health["components"]["control"]
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()
        daemon.stop()
    assert "driver fault" not in daemon.log(), daemon.log()[-3000:]
