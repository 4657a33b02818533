# One contract over every registered component: its section, routes and topics are documented,
# and what it plugs into the daemon goes when it stops (its settings: test_settings_declaration.py).
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from daemon.config import SETTINGS, all_sections
from daemon.registry import COMPONENTS
from daemon.topics import TopicIn, TopicOut
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.net import free_port
from tests.support.wait import eventually

REPO = Path(__file__).resolve().parent.parent
DOCS = REPO / "docs"


def everything(directory: Path) -> str:
    """A config that turns every optional part on: each component section's ``enabled`` key,
    the fault-injection route and the odometry transform (recordings go to ``directory``)."""
    lines = []
    for spec in COMPONENTS:
        settings = spec.settings
        if settings is None or settings.SECTION in ("http", "rosbridge"):
            continue  # the test robot sets their addresses; they are on by default
        extra = {"control": ["allow_fault_injection = true", "enable_odom_tf = true"],
                 "recorder": [f'directory = "{directory}"'],
                 "foxglove": ['host = "127.0.0.1"', f"port = {free_port()}"],
                 "fleet": [f'router = "tcp/127.0.0.1:{free_port()}"'],
                 }.get(settings.SECTION, [])
        enabled = ["enabled = true"] if "enabled" in settings.OPTIONS else []
        if enabled or extra:
            lines += [f"[{settings.SECTION}]", *enabled, *extra]
    return "\n".join(lines) + "\n"


def doc(name: str) -> str:
    return (DOCS / name).read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def declared(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """What each component of a simulated daemon with everything on declared."""
    import asyncio

    async def collect() -> dict[str, Any]:
        workdir = tmp_path_factory.mktemp("everything")
        async with in_process_daemon(workdir, everything(workdir / "recordings")) as robot:
            return _declarations(robot)

    return asyncio.run(collect())


def _declarations(robot: InProcessDaemon) -> dict[str, Any]:
    return {c.name: {"routes": list(c.routes()), "topics": list(c.topics())}
            for c in robot.daemon.components}


def test_every_row_of_the_table_builds_a_component_of_its_name(declared: dict[str, Any]) -> None:
    assert [spec.name for spec in COMPONENTS] == list(declared)


@pytest.mark.parametrize("spec", COMPONENTS, ids=lambda s: s.name)
def test_its_section_is_documented_and_in_the_example_config(spec: Any) -> None:
    if spec.settings is None:
        pytest.skip(f"{spec.name} reads only the core sections")
    section = spec.settings.SECTION
    assert f"`[{section}]`" in doc("configuration.md"), f"[{section}] in docs/configuration.md"
    example = (REPO / "systemd" / "arbiterd.toml.example").read_text()
    assert re.search(rf"^#? ?\[{re.escape(section)}\]$", example, re.M), section


@pytest.mark.parametrize("spec", COMPONENTS, ids=lambda s: s.name)
def test_its_routes_are_in_the_http_api_docs_with_their_access(
        spec: Any, declared: dict[str, Any]) -> None:
    text = doc("http-api.md")
    for route in declared[spec.name]["routes"]:
        row = f"| `{route.method} {route.path}` | {route.access} |"
        assert row in text, f"docs/http-api.md lacks the row {row!r} ({spec.name})"


@pytest.mark.parametrize("spec", COMPONENTS, ids=lambda s: s.name)
def test_its_topics_are_in_the_rosbridge_and_recorder_docs(
        spec: Any, declared: dict[str, Any]) -> None:
    rosbridge, foxglove = doc("rosbridge.md"), doc("foxglove.md")
    for topic in declared[spec.name]["topics"]:
        if isinstance(topic, TopicIn) or topic.bridge:
            assert re.search(rf"^\| `{re.escape(topic.name)}` \| `{re.escape(topic.type)}`",
                             rosbridge, re.M), f"docs/rosbridge.md: {topic.name}"
        if isinstance(topic, TopicOut) and topic.record:
            assert re.search(rf"^\|[^|\n]*`{re.escape(topic.name)}`[^|\n]*\|[^|\n]*"
                             rf"`{re.escape(topic.type)}`", foxglove, re.M), \
                f"docs/foxglove.md, recorded channels: {topic.name}"


def test_one_owner_per_topic_and_an_accepting_type_for_each_incoming_one(
        declared: dict[str, Any]) -> None:
    names = [t.name for d in declared.values() for t in d["topics"]]
    assert len(names) == len(set(names))
    for d in declared.values():
        for topic in d["topics"]:
            if isinstance(topic, TopicIn):
                assert topic.type in topic.accepted_types()


def test_every_section_but_the_drivers_has_typed_settings() -> None:
    assert [s for s in all_sections() if not s.startswith("driver.")] == list(SETTINGS)


async def test_what_a_component_plugs_in_goes_when_the_daemon_stops(tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path) as robot:
        control, bus = robot.control, robot.ctx.bus
        assert len(control.schedule) >= 4  # the components' periodic state publications
        assert len(control.tick_sources) == 1  # navigation's pose history (autonomy is off)
        assert len(control.on_tick) == len(control.on_command) == 0  # nothing busy
        autonomy = robot.ctx.components["autonomy"]
        autonomy.set_mode("wander", "test")
        assert len(control.tick_sources) == 2 and len(control.on_command) == 1
        assert "safety" in control.status_fields and "ground_truth" in control.status_fields
        assert bus.subscribers(_scan_key()) >= 2
    assert len(control.on_tick) == 0  # the daemon's own (the systemd watchdog's) needs systemd
    assert len(control.tick_sources) == 0 and len(control.on_command) == 0
    assert len(control.schedule) == 0
    assert [name for name, _ in control.status_fields.items()] == [
        "measured_wheel_speeds_rad_s"]
    assert control.guard is None and bus.subscribers(_scan_key()) == 0


def _scan_key() -> Any:
    from daemon.telemetry import SCAN

    return SCAN


async def test_the_bridge_and_the_recorder_listen_to_the_bus_only_while_someone_watches(
        tmp_path: Path) -> None:
    """A topic nobody watches costs its publisher (the control tick, every command) nothing:
    the bridge subscribes to a robot topic's bus key while a client subscribes to the topic,
    and the recorder to the recorded topics while recording is on."""
    from daemon.telemetry import COMMAND, ODOM

    async with in_process_daemon(tmp_path, '[recorder]\nenabled = false\ndirectory = "'
                                 f'{tmp_path / "rec"}"\n') as robot:
        bus = robot.ctx.bus
        quiet = bus.subscribers(ODOM), bus.subscribers(COMMAND)
        async with aiohttp.ClientSession() as session, session.ws_connect(robot.ws_url) as ws:
            await ws.send_json({"op": "subscribe", "topic": "/odom", "id": "odom"})
            frame = await ws.receive_json(timeout=5)  # the latest /odom, then each new one
            assert frame["topic"] == "/odom"
            assert bus.subscribers(ODOM) == quiet[0] + 1
            assert bus.subscribers(COMMAND) == quiet[1]
            await ws.send_json({"op": "unsubscribe", "topic": "/odom", "id": "odom"})
            await eventually(lambda: bus.subscribers(ODOM) == quiet[0], "the bridge to let go")
        recorder = robot.ctx.components["recorder"]
        recorder.set_recording(True)
        assert bus.subscribers(ODOM) == quiet[0] + 1 and bus.subscribers(COMMAND) == quiet[1] + 1
        recorder.set_recording(False)
        assert (bus.subscribers(ODOM), bus.subscribers(COMMAND)) == quiet
