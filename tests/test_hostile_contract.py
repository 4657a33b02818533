# Every declared HTTP route and incoming topic, from the component table, vs the hostile corpus.
from __future__ import annotations

import asyncio
import contextlib
import resource
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from aiohttp import web

from daemon.bench.rosbridge_flood import MachineCanary
from tests.support.hostile import (
    Findings,
    LoopCanary,
    concrete_paths,
    hammer_route,
    never_reading,
    publish_frame,
    topic_corpus,
)
from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon
from tests.support.rosbridge import TOKEN, WITH_TOKEN
from tests.support.topic_samples import everything
from tests.support.wait import eventually

#: what a never-reading client may hold: send_timeout_s and idle_timeout_s (both 1 s here)
TIMEOUTS = {"ARBITERD_HTTP_SEND_TIMEOUT_S": "1", "ARBITERD_HTTP_IDLE_TIMEOUT_S": "1"}
#: the loop may stall this long beyond what the machine's load does to an idle process
#: (the findings: 6.9 s for a big map)
STALL_LIMIT_S = 1.0
#: what the run may add to this process's peak memory (daemon and test together)
MEMORY_LIMIT_MB = 300
#: big files where the daemon serves files: the routes' placeholders take these names too
BIG_FILES = {"mapping": ("big.pgm", "big.yaml"), "recorder": ("arbiterd-big.mcap",)}


@pytest.fixture
async def robot(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                ) -> AsyncIterator[InProcessDaemon]:
    for key, value in TIMEOUTS.items():
        monkeypatch.setenv(key, value)
    config = everything(tmp_path) + WITH_TOKEN + "read_requires_token = true\n"
    config = config.replace(f'directory = "{tmp_path / "record"}"',
                            f'directory = "{tmp_path / "recorder"}"')
    for section, names in BIG_FILES.items():
        directory = tmp_path / section
        directory.mkdir(exist_ok=True)
        for name in names:
            with (directory / name).open("wb") as sparse:
                sparse.truncate(8 * 1024 * 1024)
    async with in_process_daemon(tmp_path, config) as robot:
        yield robot


def wheel_commands(robot: InProcessDaemon) -> list[Any]:
    return list(robot.driver.commands)


def moved(commands: list[Any]) -> bool:
    return any(abs(c.left_rad_s) > 1e-6 or abs(c.right_rad_s) > 1e-6 for c in commands)


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


async def test_every_route_and_topic_survives_the_hostile_corpus(robot: InProcessDaemon) -> None:
    """No 5xx, no traceback, no stall of the loop, no motion, memory bounded, and the
    never-reading clients of every route let go within the server's timeouts."""
    findings = Findings()
    canary = LoopCanary(findings)
    rss, commands = peak_rss_mb(), len(robot.driver.commands)
    findings.broken = set(_health_errors(robot))
    first_motion: list[str] = []

    async def watch_motion() -> None:
        seen = commands
        while not first_motion:
            await asyncio.sleep(0.005)
            if moved(wheel_commands(robot)[seen:]):
                first_motion.append(findings.current)
            seen = len(robot.driver.commands)

    watcher = asyncio.get_running_loop().create_task(watch_motion())
    async with MachineCanary() as machine:  # the in-run baseline: the machine's own load
        canary.start()
        try:
            await _routes(robot, findings)
            await _never_reading_clients(robot, findings)
            await _topics(robot, findings)
        finally:
            canary.stop()
            watcher.cancel()
    limit_s = STALL_LIMIT_S + machine.longest_gap_ms / 1000
    print(f"hostile corpus: {len(findings.routes)} routes, {len(findings.topics)} topics, "
          f"{findings.requests} requests; worst loop stall {1000 * canary.worst:.0f} ms "
          f"({canary.during}; an idle process meanwhile: {machine.longest_gap_ms:.0f} ms); "
          f"peak memory +{peak_rss_mb() - rss:.0f} MB")
    assert not findings.problems, "\n".join(findings.problems)
    assert not moved(wheel_commands(robot)[commands:]), f"the robot moved: {first_motion}"
    assert canary.worst < limit_s, f"the loop stalled {canary.worst:.2f} s during {canary.during}"
    assert peak_rss_mb() - rss < MEMORY_LIMIT_MB
    table = robot.ctx.http.access_table()
    assert len(findings.routes) == len({(m, p) for m, p, _ in table if m != "HEAD"})
    assert findings.topics == {t.name for t in robot.ctx.topics.incoming()}


async def _routes(robot: InProcessDaemon, findings: Findings) -> None:
    async with aiohttp.ClientSession() as session:
        for method, path, _ in robot.ctx.http.access_table():
            if method == "HEAD" or (method, path) == ("POST", "/api/debug/stall"):
                continue  # HEAD: its GET's; the stall is fault injection, stalling on purpose
            await hammer_route(session, robot.http_url, method, path, TOKEN, findings)
            await _release(robot, findings)
    findings.routes.add("POST /api/debug/stall")


def _health_errors(robot: InProcessDaemon) -> dict[str, str]:
    return {c.name: str(h.problem) for c in robot.daemon.components
            if (h := c.health()) is not None and h.status == "error"}


async def _release(robot: InProcessDaemon, findings: Findings) -> None:
    """A component the corpus broke (health error) is a finding; what a hostile body may
    legitimately have done (latched the e-stop) is undone, so that the next route is tried
    on a robot that could move."""
    for name, problem in _health_errors(robot).items():
        if name not in findings.broken:
            findings.broken.add(name)
            findings.add(name, findings.current, f"health error: {problem}")
    control = robot.control
    if control.estop_engaged:
        async with aiohttp.ClientSession() as session, session.post(
                robot.http_url + "/api/estop", json={"engaged": False},
                headers={"Authorization": f"Bearer {TOKEN}"}):
            pass


async def _never_reading_clients(robot: InProcessDaemon, findings: Findings) -> None:
    """Four clients per GET route (each concrete path) that never read their answer: the
    server lets every one go within send_timeout_s + idle_timeout_s (1 s each here)."""
    port = int(robot.http_url.rsplit(":", 1)[1])
    clients = []
    findings.current = "never-reading clients"
    for method, path, _ in robot.ctx.http.access_table():
        if method != "GET":
            continue
        for concrete in {*concrete_paths(path), *_big_paths(path)}:
            clients += await never_reading(port, method, concrete, TOKEN, 4)
    http = robot.component("http")
    try:
        await eventually(lambda: http.health().values["connections"] <= 2,
                         "the never-reading clients let go", within_s=20)
    except AssertionError:
        for sock in clients:
            sock.close()
        await _name_the_holders(robot, port, findings)
    finally:
        for sock in clients:
            sock.close()


async def _name_the_holders(robot: InProcessDaemon, port: int, findings: Findings) -> None:
    """Route by route: which one holds its never-reading clients."""
    http = robot.component("http")
    for method, path, _ in robot.ctx.http.access_table():
        if method != "GET":
            continue
        for concrete in {*concrete_paths(path), *_big_paths(path)}:
            await eventually(lambda: http.health().values["connections"] <= 2, "quiet")
            clients = await never_reading(port, method, concrete, TOKEN, 4)
            try:
                await eventually(lambda: http.health().values["connections"] <= 2,
                                 "the never-reading clients let go", within_s=5)
            except AssertionError:
                findings.add(f"GET {concrete[:60]}", "never-reading clients",
                             f"{http.health().values['connections']} connections held")
            finally:
                for sock in clients:
                    sock.close()


def _big_paths(path: str) -> list[str]:
    names = [name for names in BIG_FILES.values() for name in names]
    return [path.split("{")[0] + name for name in names] if "{" in path else []


async def _topics(robot: InProcessDaemon, findings: Findings) -> None:
    """Each incoming topic's corpus from a client with the token, one with a wrong token
    and one without: the session answers (or closes), the daemon logs no traceback."""
    for who, query in (("right token", f"?token={TOKEN}"), ("no token", ""),
                       ("wrong token", "?token=not-the-token-0")):
        for topic in robot.ctx.topics.incoming():
            findings.topics.add(topic.name)
            for case, msg in topic_corpus(topic.type):
                findings.requests += 1
                findings.current = f"{topic.name} [{case}, {who}]"
                await _publish(robot.ws_url + query, topic.name, topic.type, msg,
                               f"{case}, {who}", findings)
            await _release(robot, findings)


async def _publish(url: str, topic: str, type_name: str, msg: Any, case: str,
                   findings: Findings) -> None:
    frame = publish_frame(topic, type_name, msg)
    try:
        async with aiohttp.ClientSession() as session, asyncio.timeout(15):
            try:
                ws = await session.ws_connect(url, max_msg_size=0)
            except aiohttp.WSServerHandshakeError as exc:
                if exc.status >= 500:
                    findings.add(topic, case, f"upgrade answered {exc.status}")
                return
            async with ws:
                await ws.send_str(json_advertise(topic, type_name))
                await ws.send_str(frame)
                await ws.send_str('{"op": "call_service", "service": "/rosapi/topics", '
                                  '"id": "alive"}')
                await _answered(ws, topic, case, findings)
    except TimeoutError:
        findings.add(topic, case, "no answer within 15 s")


def json_advertise(topic: str, type_name: str) -> str:
    return f'{{"op": "advertise", "topic": "{topic}", "type": "{type_name}"}}'


async def _answered(ws: aiohttp.ClientWebSocketResponse, topic: str, case: str,
                    findings: Findings) -> None:
    """Read until the liveness call is answered or the server closes the socket."""
    while True:
        message = await ws.receive()
        if message.type != aiohttp.WSMsgType.TEXT:
            return  # closed by the server: allowed for a client that broke the protocol
        if "Traceback" in message.data:
            findings.add(topic, case, "a traceback in a status message")
        if '"id": "alive"' in message.data or '"id":"alive"' in message.data:
            return


# -- the deliberate break ---------------------------------------------------------------------

async def test_a_route_added_without_a_bound_fails_the_contract(tmp_path: Path) -> None:
    """The same checks against a server with two routes that skip the kernel's bounds: one
    that indexes a grid with the body's x unchecked (1e308 answers 500), one that streams a
    file itself instead of through ``send_file`` (never-reading clients hold it; an answer a
    handler returns, ``web.FileResponse`` included, is watched by the server)."""
    from base.options import defaults
    from daemon.components.http.component import HttpServer
    from daemon.components.http.settings import HttpSettings
    from daemon.security import Security
    from tests.support.net import free_port

    big = tmp_path / "big.bin"
    with big.open("wb") as sparse:
        sparse.truncate(8 * 1024 * 1024)

    async def unchecked_goal(request: web.Request) -> web.Response:
        body = await server.read_json(request)
        cell = int(float(body.get("x", 0)) / 0.05 * 1e10)  # OverflowError past 1e298
        return web.json_response({"cell": cell})

    async def unbounded_file(request: web.Request) -> web.StreamResponse:
        response = web.StreamResponse()  # streamed by the handler itself, not send_file
        await response.prepare(request)
        with big.open("rb") as file:
            while chunk := file.read(65536):
                await response.write(chunk)
        return response

    port = free_port()
    settings = HttpSettings.from_values(defaults(HttpSettings.OPTIONS) | {
        "host": "127.0.0.1", "port": port, "send_timeout_s": 1.0, "idle_timeout_s": 1.0})
    server = HttpServer(settings, Security(TOKEN, own_names=()))
    server.add_route("POST", "/api/unchecked", unchecked_goal)
    server.add_route("GET", "/api/unbounded/{file}", unbounded_file, access="read")
    await server.start()
    findings = Findings()
    clients = []
    try:
        async with aiohttp.ClientSession() as session:
            await hammer_route(session, f"http://127.0.0.1:{port}", "POST", "/api/unchecked",
                               TOKEN, findings)
        clients = await never_reading(port, "GET", "/api/unbounded/x", TOKEN, 4)
        with contextlib.suppress(AssertionError):
            await eventually(lambda: len(server._runner.server.connections) == 0,  # type: ignore[union-attr]
                             "the never-reading clients let go", within_s=4)
        held = len(server._runner.server.connections)  # type: ignore[union-attr]
    finally:
        for sock in clients:
            sock.close()
        await server.stop()
    print(f"deliberate break: {len(findings.problems)} findings, e.g. {findings.problems[:1]}; "
          f"{held} never-reading clients still held")
    assert any("500" in p for p in findings.problems) and held == 4
