# A bounded WebSocket fuzz and load run: every category tried, memory flat, loop live, robot still.
from __future__ import annotations

from pathlib import Path
from typing import Any

from daemon.bench.rosbridge_attacks import TEXT_CATEGORIES, run_attack
from daemon.bench.rosbridge_flood import measure, rss_mb
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rosbridge import OWNER, TWIST, WITH_TOKEN, bridge, connect, stall_limit_ms
from tests.support.wait import eventually

WARM_UP_S = 5
FUZZ_S = 25
RSS_GROWTH_MB = 30.0  # after the warm-up; the daemon in this test process holds ~100 MB


def nothing_moved(robot: InProcessDaemon) -> None:
    wheels = [(c.left_rad_s, c.right_rad_s) for c in robot.driver.commands]
    assert all(left == 0.0 and right == 0.0 for left, right in wheels), "a wheel turned"
    # the fuzzers may have latched the e-stop (anyone may stop the robot), never released it
    graph = bridge(robot).graph
    assert not graph.services and not graph.pending
    assert not any(topic.publishers for topic in graph.topics.values())


async def test_tokenless_fuzz_moves_nothing_and_leaks_nothing(
        tmp_path: Path, record_property: Any) -> None:
    async with in_process_daemon(tmp_path, WITH_TOKEN) as robot:
        await run_attack(robot.ws_url, "fuzz", "--seconds", str(WARM_UP_S), "--seed", "1")
        rss_before = rss_mb()
        window = await measure(robot.daemon, run_attack(
            robot.ws_url, "fuzz", "--seconds", str(FUZZ_S), "--seed", "2"), 0)
        await eventually(lambda: not bridge(robot).clients, "the fuzzers to be gone")
        rss_after = rss_mb()
        report = window.detail
        summary = {"inputs": report["inputs"], "total_inputs": report["total_inputs"],
                   "replies": report["replies"], "reconnects": report["reconnects"],
                   "rss_before_mb": round(rss_before, 1), "rss_after_mb": round(rss_after, 1),
                   "longest_stall_ms": round(window.longest_stall_ms, 1),
                   "tick_max_ms": round(window.tick_max_ms, 1),
                   "machine_stall_ms": round(window.machine_stall_ms, 1)}
        record_property("rosbridge_fuzz", summary)
        print(f"\nrosbridge fuzz: {summary}")
        assert set(report["inputs"]) == {*TEXT_CATEGORIES, "binary", "wire"}
        assert min(report["inputs"].values()) >= 10, report["inputs"]
        assert report["replies"].get("status", 0) > 0
        nothing_moved(robot)
        assert window.longest_stall_ms < stall_limit_ms(window.machine_stall_ms), summary
        assert rss_after - rss_before < RSS_GROWTH_MB, summary
        await still_drives_with_the_token(robot)


async def still_drives_with_the_token(robot: InProcessDaemon) -> None:
    async with connect(robot.ws_url, headers=OWNER) as owner:
        assert (await owner.call("/rosapi/get_time"))["result"] is True
        await owner.send(op="publish", topic="/estop", msg={"data": False})
        await owner.send(op="publish", topic="/cmd_vel", msg=TWIST)
        await eventually(robot.moving, "the token holder to drive after the fuzz")


async def test_fuzz_without_a_token_configured_keeps_the_bridge_answering(
        tmp_path: Path) -> None:
    """Without a token configured every client may drive: the same junk is refused field by
    field, and the bridge keeps answering."""
    async with in_process_daemon(tmp_path) as robot:
        report = await run_attack(robot.ws_url, "fuzz", "--seconds", "5", "--seed", "3")
        assert report["replies"].get("status", 0) > 0
        async with connect(robot.ws_url) as client:
            assert (await client.call("/rosapi/get_time"))["result"] is True
        assert not robot.control.fault
