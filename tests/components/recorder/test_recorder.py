# The flight recorder's writer on real files: decoding, rotation, the disk cap, drops, a quota.
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import tomllib
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from daemon.components.recorder.channels import channels_by_bus
from daemon.components.recorder.files import inspect
from daemon.components.recorder.paths import default_directory
from daemon.components.recorder.writer import FlightRecorder, WriterOptions, recordings
from daemon.config import load_config
from daemon.messages.convert import odometry_msg, scan_msg, tf_msg
from daemon.messages.definitions import LASER_SCAN, ODOMETRY, TF_MESSAGE
from daemon.telemetry import ODOM as ODOM_KEY
from daemon.telemetry import SCAN as SCAN_KEY
from daemon.telemetry import OdomSample, Transform
from daemon.topics import TopicOut
from sensors.scan import LaserScan
from tests.support.paths import REPO
from tests.support.wait import wait_for


def odometry_tf(sample: OdomSample) -> dict[str, Any]:
    """/tf from the odometry sample itself: one bus message, two channels."""
    return tf_msg((Transform.of_odometry(sample),))


CHANNELS = channels_by_bus([TopicOut("/odom", ODOMETRY, ODOM_KEY, odometry_msg, "20 Hz"),
                            TopicOut("/tf", TF_MESSAGE, ODOM_KEY, odometry_tf, "20 Hz"),
                            TopicOut("/scan", LASER_SCAN, SCAN_KEY, scan_msg, "10 Hz")])
ODOM = tuple(CHANNELS["odom"])
SCAN = tuple(CHANNELS["scan"])


def options(directory: Path, **overrides: Any) -> WriterOptions:
    values: dict[str, Any] = {
        "directory": directory, "max_file_bytes": 64_000_000, "max_file_s": 900.0,
        "max_total_bytes": 1_000_000_000, "compression": "zstd", "flush_interval_s": 0.05,
        "queue_size": 10000}
    return WriterOptions(**(values | overrides))


def odom(i: int) -> OdomSample:
    return OdomSample(1700000000.0 + i * 0.05, "odom", "base_link", i * 0.01, 0.0, 0.0, 0.2,
                      0.0, [0.1] * 6, [0.1] * 6)


def scan(i: int, rays: int = 720) -> LaserScan:
    rng = np.random.default_rng(i)  # incompressible enough that files grow
    return LaserScan(stamp=1700000000.0 + i * 0.1, ranges=rng.uniform(0.2, 8, rays).astype(
        np.float32), intensities=np.zeros(rays, np.float32), range_max=12.0)


@pytest.fixture
def recorder(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[FlightRecorder]:
    overrides = getattr(request, "param", {})
    all_channels = [c for group in CHANNELS.values() for c in group]
    rec = FlightRecorder(options(tmp_path / "rec", **overrides), all_channels)
    rec.wanted = True
    rec.start()
    yield rec
    rec.stop()


def decoded(path: Path) -> list[tuple[str, int, Any]]:
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [(channel.topic, message.log_time, msg)
                for _, channel, message, msg in reader.iter_decoded_messages()]


def test_messages_come_back_decoded_in_time_order(recorder: FlightRecorder) -> None:
    for i in range(40):
        recorder.enqueue(ODOM, odom(i))
    recorder.enqueue(SCAN, scan(0))
    wait_for(lambda: recorder.written >= 81, "the writer to take every message")
    path = recorder.current
    recorder.stop()
    assert path is not None and inspect(path).complete
    messages = decoded(path)
    topics = [t for t, _, _ in messages]
    assert topics.count("/odom") == 40 and topics.count("/tf") == 40 and "/scan" in topics
    times = [t for _, t, _ in messages]
    assert times == sorted(times)
    xs = [m.pose.pose.position.x for t, _, m in messages if t == "/odom"]
    assert xs == pytest.approx([i * 0.01 for i in range(40)])


@pytest.mark.parametrize("recorder", [{"max_file_bytes": 100_000, "compression": "none"}],
                         indirect=True)
def test_files_rotate_by_size(recorder: FlightRecorder) -> None:
    def fed() -> bool:
        recorder.enqueue(SCAN, scan(recorder.written))
        return recorder.files_started >= 3

    wait_for(fed, "three files")
    current = recorder.current
    closed = [p for p in recordings(recorder.options.directory) if p != current]
    assert len(closed) >= 2
    for path in closed:
        info = inspect(path)
        assert info.complete and info.topics["/scan"].count > 0
        size = path.stat().st_size  # rotation happens at the first flush past the limit
        assert 100_000 <= size < 200_000


@pytest.mark.parametrize("recorder", [{"max_file_s": 0.3}], indirect=True)
def test_files_rotate_by_age(recorder: FlightRecorder) -> None:
    def fed() -> bool:
        recorder.enqueue(ODOM, odom(recorder.written))
        return recorder.files_started >= 3

    wait_for(fed, "three files", interval_s=0.02)
    assert all(inspect(p).complete for p in recordings(recorder.options.directory)
               if p != recorder.current)


@pytest.mark.parametrize("recorder", [{"max_file_bytes": 30_000, "max_total_bytes": 100_000,
                                       "compression": "none"}], indirect=True)
def test_the_disk_cap_deletes_the_oldest_files(recorder: FlightRecorder) -> None:
    directory = recorder.options.directory
    first_names: set[str] = set()

    def fed() -> bool:
        recorder.enqueue(SCAN, scan(recorder.written))
        if recorder.files_started <= 2:
            first_names.update(p.name for p in recordings(directory))
        return recorder.files_started >= 8

    wait_for(fed, "eight files")
    recorder.stop()
    remaining = recordings(directory)
    assert recorder.deleted > 0
    assert sum(p.stat().st_size for p in remaining) <= 100_000 + 30_000
    assert not first_names & {p.name for p in remaining}  # the oldest went first


def test_a_full_queue_drops_and_counts(tmp_path: Path) -> None:
    rec = FlightRecorder(options(tmp_path, queue_size=100), list(ODOM))
    rec.wanted = True  # the thread is not started: nothing drains
    for i in range(150):
        rec.enqueue(ODOM, odom(i))
    assert (rec.queued, rec.dropped) == (100, 50)


def test_nothing_is_queued_while_disabled(tmp_path: Path) -> None:
    rec = FlightRecorder(options(tmp_path), list(ODOM))
    rec.enqueue(ODOM, odom(0))
    assert rec.queued == 0


def test_an_unwritable_directory_is_an_error_naming_it(tmp_path: Path) -> None:
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    rec = FlightRecorder(options(blocker / "recordings"), list(ODOM))
    rec.wanted = True
    rec.start()
    try:
        rec.enqueue(ODOM, odom(0))
        error = wait_for(lambda: rec.error, "the recorder's error")
        assert str(blocker / "recordings") in error and "[recorder] directory" in error
        wait_for(lambda: rec.lost >= 1, "the queued message to be counted as lost")
    finally:
        rec.stop()


QUOTA_SCRIPT = textwrap.dedent("""
    import json, resource, signal, sys, time
    from pathlib import Path
    from tests.components.recorder.test_recorder import CHANNELS, SCAN, options, scan
    from daemon.components.recorder.writer import FlightRecorder
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
    resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))
    rec = FlightRecorder(options(Path(sys.argv[1]), compression="none"), list(SCAN))
    rec.wanted = True
    rec.start()
    deadline = time.monotonic() + 20
    i = 0
    while rec.error is None and time.monotonic() < deadline:
        rec.enqueue(SCAN, scan(i))
        i += 1
        time.sleep(0.01)
    rec.stop()
    print(json.dumps(rec.snapshot()))
""")


def test_a_file_size_quota_pauses_recording_with_an_error(tmp_path: Path) -> None:
    """RLIMIT_FSIZE stands in for a full disk: writes past it fail as they would on ENOSPC."""
    result = subprocess.run([sys.executable, "-c", QUOTA_SCRIPT, str(tmp_path / "rec")],
                            cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    state = json.loads(result.stdout.splitlines()[-1])
    assert state["error"] and "cannot write" in state["error"]
    assert str(tmp_path / "rec") in state["error"]
    (path,) = recordings(tmp_path / "rec")
    info = inspect(path)  # cut short, yet what reached the disk reads back
    assert not info.complete and info.topics["/scan"].count > 0


def test_files_go_to_the_service_state_directory_by_default(tmp_path: Path) -> None:
    assert default_directory({"STATE_DIRECTORY": "/var/lib/arbiterd"}) == Path(
        "/var/lib/arbiterd/recordings")
    assert default_directory({"XDG_STATE_HOME": str(tmp_path)}) == (
        tmp_path / "arbiterd" / "recordings")


def test_the_service_records_and_a_plain_config_does_not(tmp_path: Path) -> None:
    assert load_config(REPO / "systemd" / "arbiterd.toml.example", env={})["recorder"]["enabled"]
    (tmp_path / "plain.toml").write_text("")
    assert not load_config(tmp_path / "plain.toml", env={})["recorder"]["enabled"]


def documented_recipe() -> Any:
    """The `messages(path)` recipe of docs/foxglove.md, as printed there."""
    text = (REPO / "docs" / "foxglove.md").read_text()
    (block,) = [b for b in text.split("```python\n")[1:] if "def messages(path)" in b]
    namespace: dict[str, Any] = {}
    exec(block.split("```")[0], namespace)
    return namespace["messages"]


def record_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "daemon.cli", "record", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=60)


def test_a_file_being_recorded_says_so_and_the_documented_recipe_reads_it(
        recorder: FlightRecorder) -> None:
    for i in range(40):
        recorder.enqueue(ODOM, odom(i))
    path = wait_for(lambda: recorder.current, "the file to open")
    wait_for(lambda: inspect(path).messages == 80, "the messages to reach the disk")
    info = inspect(path)
    assert not info.complete and info.recording
    messages = documented_recipe()
    assert [(t, m.child_frame_id) for t, _, m in messages(path) if t == "/odom"] == [
        ("/odom", "base_link")] * 40
    directory = recorder.options.directory
    described = record_cli("info", path.name, "--dir", str(directory))
    assert described.returncode == 0, described.stderr
    assert f"{path}: " in described.stdout
    assert "being recorded: read up to its last whole chunk" in described.stdout
    assert "(being recorded)" in record_cli("list", "--dir", str(directory)).stdout
    recorder.wanted = False
    wait_for(lambda: recorder.current is None, "the file to close")
    info = inspect(path)
    assert info.complete and not info.recording
    assert len(list(messages(path))) == 80
    assert "complete" in record_cli("info", path.name, "--dir", str(directory)).stdout


def test_record_info_of_an_unknown_name_says_where_it_looked(tmp_path: Path) -> None:
    done = record_cli("info", "arbiterd-nothing.mcap", "--dir", str(tmp_path))
    assert done.returncode == 2
    assert done.stderr == (
        f"arbiterd record info: arbiterd-nothing.mcap: no such file here nor in {tmp_path}; "
        "`arbiterd record list` prints the recordings' names (--dir DIR or --config FILE looks "
        "in another directory)\n")


def test_the_python_reader_of_the_docs_comes_with_arbiterd_and_is_pure_python() -> None:
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert any(dep.startswith("mcap-ros2-support") for dep in project["dependencies"])
    for name in ("mcap", "mcap-ros2-support"):  # wheels for the Pi's aarch64 too
        assert "Root-Is-Purelib: true" in (metadata.distribution(name).read_text("WHEEL") or "")
