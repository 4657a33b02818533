# Every HTTP route declares its access; with a token, nothing answers without it but the open ones.
from __future__ import annotations

import re
from collections.abc import AsyncIterator
from pathlib import Path

import aiohttp
import pytest

from tests.support.in_process_daemon import InProcessDaemon, in_process_daemon

TOKEN = "s3cret-Token"
DOC = Path(__file__).resolve().parent.parent / "docs" / "http-api.md"
# The web console's routes (page and files), open in every configuration.
CONSOLE = {("GET", "/"), ("HEAD", "/"), ("GET", "/console/{name}"), ("HEAD", "/console/{name}")}
# Latching the e-stop needs no token (releasing it does: the handler asks once it read the body).
STOP = {("POST", "/api/estop")}
LOCKED = (f'[security]\ntoken = "{TOKEN}"\nread_requires_token = true\n'
          '[control]\nallow_fault_injection = true\n')


def locked_toml(tmp_path: Path) -> str:
    """LOCKED with every optional component on (its maps in the test's own folder)."""
    return LOCKED + f'[mapping]\nenabled = true\ndirectory = "{tmp_path / "maps"}"\n' \
        '[arm]\nenabled = true\n[battery]\nenabled = true\ndevice = "sim"\n' \
        '[camera]\nenabled = true\n'


@pytest.fixture
async def locked(tmp_path: Path) -> AsyncIterator[InProcessDaemon]:
    """Token configured, reads need it too, every optional route registered (sim, lidar,
    fault injection, mapping, the arm, the battery)."""
    async with in_process_daemon(tmp_path, locked_toml(tmp_path)) as robot:
        yield robot


def routes(robot: InProcessDaemon) -> list[tuple[str, str, str]]:
    table: list[tuple[str, str, str]] = robot.ctx.http.access_table()
    return table


def concrete(path: str) -> str:
    """A request path for a route pattern (``/api/recordings/{name}`` -> ``.../x``)."""
    return re.sub(r"\{[^}]+\}", "x", path)


async def status_of(robot: InProcessDaemon, method: str, path: str,
                    token: str | None = None) -> int:
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    async with aiohttp.ClientSession() as session, session.request(
            method, robot.http_url + concrete(path), headers=headers) as response:
        return response.status  # the status line only: a stream (the camera's) never ends


def test_access_levels_are_checked_at_registration() -> None:
    from base.options import defaults
    from daemon.components.http.component import HttpServer
    from daemon.components.http.settings import HttpSettings
    from daemon.security import Security

    http = HttpServer(HttpSettings.from_values(defaults(HttpSettings.OPTIONS) | {
        "host": "127.0.0.1", "port": 0, "max_body_bytes": 1024, "body_timeout_s": 1.0,
        "idle_timeout_s": 1.0, "max_connections": 8}), Security(""))

    async def handler(request: object) -> object:
        raise AssertionError("never called")

    with pytest.raises(ValueError, match="access must be one of"):
        http.add_route("GET", "/x", handler, access="public")  # type: ignore[arg-type]
    http.add_route("POST", "/y", handler)
    assert http.access_table() == [("POST", "/y", "drive")]


async def test_every_route_is_in_the_access_table(locked: InProcessDaemon) -> None:
    declared = {(m, p) for m, p, _ in routes(locked)}
    in_router = {(r.method, r.resource.canonical) for r in locked.ctx.http.app.router.routes()
                 if r.resource is not None}
    assert in_router == declared
    paths = {p for _, p, _ in routes(locked)}
    assert {"/api/health", "/api/scan", "/api/sim/metrics", "/api/sim/reset", "/api/cmd_vel",
            "/api/estop", "/api/debug/stall"} <= paths


async def test_without_the_token_every_route_answers_401(locked: InProcessDaemon) -> None:
    """All but the web console's page and files, which must load to ask for the token, and
    the e-stop, which anyone may latch."""
    opened = {(m, p) for m, p, a in routes(locked) if a == "open"}
    assert opened == CONSOLE
    assert {(m, p) for m, p, a in routes(locked) if a == "stop"} == STOP
    refused = {(m, p): await status_of(locked, m, p) for m, p, a in routes(locked)
               if a not in ("open", "stop")}
    assert refused and all(status == 401 for status in refused.values()), refused
    assert await status_of(locked, "GET", "/") == 200
    assert await status_of(locked, "POST", "/api/estop") == 415  # on to the body: no 401
    assert not locked.moving()


async def test_with_the_token_no_route_answers_401(locked: InProcessDaemon) -> None:
    for method, path, _ in routes(locked):
        # no body: the POSTs stop at 415, so nothing moves and nothing stalls
        status = await status_of(locked, method, path, TOKEN)
        assert status not in (401, 403), (method, path, status)


@pytest.mark.parametrize(("method", "path"), [
    ("GET", "/api/scan"), ("GET", "/api/sim/metrics"), ("POST", "/api/sim/reset"),
])
async def test_the_three_formerly_open_routes_need_the_token(locked: InProcessDaemon, method: str,
                                                             path: str) -> None:
    assert await status_of(locked, method, path) == 401
    assert await status_of(locked, method, path, "wrong") == 401
    assert await status_of(locked, method, path, TOKEN) not in (401, 403)


async def test_open_health_is_the_documented_exception(tmp_path: Path) -> None:
    config = locked_toml(tmp_path).replace("read_requires_token = true\n",
                            "read_requires_token = true\nopen_health = true\n")
    async with in_process_daemon(tmp_path, config) as robot:
        opened = {(m, p) for m, p, a in routes(robot) if a == "open"}
        assert opened == {("GET", "/api/health"), ("HEAD", "/api/health"), *CONSOLE}
        for method, path, access in routes(robot):
            expected = {"open": 404 if "{" in path else 200, "stop": 415}.get(access, 401)
            assert await status_of(robot, method, path) == expected, (method, path)


async def test_reads_are_open_and_driving_is_not_without_read_requires_token(
        tmp_path: Path) -> None:
    async with in_process_daemon(tmp_path, f'[security]\ntoken = "{TOKEN}"\n') as robot:
        for method, path, access in routes(robot):
            status = await status_of(robot, method, path)
            if access == "drive":
                assert status == 401, (method, path)
            else:
                assert status != 401, (method, path)
        assert not robot.moving()


def documented_access() -> set[tuple[str, str, str]]:
    """The rows of the access table in docs/http-api.md: | `METHOD /path` | access | ..."""
    rows = set()
    for line in DOC.read_text().splitlines():
        match = re.match(r"\|\s*`(GET|POST|PUT|DELETE) (/\S*)`\s*\|\s*(open|stop|read|drive)\b",
                         line)
        if match:
            rows.add((match.group(1), match.group(2), match.group(3)))
    return rows


async def test_the_doc_and_the_router_agree(locked: InProcessDaemon) -> None:
    served = {(m, p, a) for m, p, a in routes(locked) if m != "HEAD"}
    assert documented_access() == served
