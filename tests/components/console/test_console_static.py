# The web console's static routes: a fixed table of files, safe headers, no path escapes.
from __future__ import annotations

import asyncio
import gzip
import re
from collections.abc import AsyncIterator
from pathlib import Path

import aiohttp
import pytest
from aiohttp import web
from aiohttp.test_utils import TestServer

from daemon.components.console.component import FILES, Console, url_of
from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.paths import REPO
from tests.support.wait import wait_for

STATIC = REPO / "daemon" / "components" / "console" / "static"


@pytest.fixture
async def server() -> AsyncIterator[TestServer]:
    console = Console(ws_port=9191)
    app = web.Application()
    for path, handler in console.routes():
        app.router.add_get(path, handler)  # and HEAD
    async with TestServer(app, host="127.0.0.1") as test_server:
        yield test_server


async def raw_get(port: int, target: str) -> tuple[int, bytes]:
    """One request with the target sent byte for byte (no client-side path cleaning)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET {target} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
                 .encode())
    data = await reader.read()
    writer.close()
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split()[1]), body


def test_the_table_and_the_static_folder_hold_the_same_files() -> None:
    on_disk = {p.name for p in STATIC.iterdir() if p.is_file()}
    assert set(FILES) == on_disk


def test_no_inline_script_or_handler_in_the_page() -> None:
    html = (STATIC / "index.html").read_text()
    scripts = re.findall(r"<script\b[^>]*>", html)
    assert scripts and all("src=" in tag for tag in scripts)
    assert not re.search(r"\son[a-z]+\s*=", html), "inline event handlers break the CSP"
    assert "style=" not in html, "inline styles break the CSP"


def test_every_module_import_is_served() -> None:
    for name in (n for n in FILES if n.endswith(".js")):
        for imported in re.findall(r'from "\./([\w.]+)"', (STATIC / name).read_text()):
            assert imported in FILES, f"{name} imports {imported}, which is not served"
    html = (STATIC / "index.html").read_text()
    for url in re.findall(r'(?:src|href)="([^"]+)"', html):
        assert url in {url_of(name) for name in FILES}, url


async def test_page_and_modules_are_served_with_safe_headers(server: TestServer) -> None:
    async with aiohttp.ClientSession() as session:
        for name in FILES:
            async with session.get(server.make_url(url_of(name))) as response:
                assert response.status == 200, name
                assert await response.read() == (STATIC / name).read_bytes()
                headers = response.headers
                assert headers["X-Content-Type-Options"] == "nosniff"
                assert "Access-Control-Allow-Origin" not in headers
        async with session.get(server.make_url("/")) as response:
            csp = response.headers["Content-Security-Policy"]
            assert response.content_type == "text/html"
    assert "script-src 'self'" in csp and "unsafe-inline" not in csp
    assert "frame-ancestors 'none'" in csp
    assert "connect-src 'self' ws://*:9191 wss://*:9191" in csp


async def test_gzip_etag_and_head(server: TestServer) -> None:
    url = server.make_url("/console/app.js")
    async with aiohttp.ClientSession(auto_decompress=False) as session:
        async with session.get(url, headers={"Accept-Encoding": "gzip"}) as response:
            assert response.headers["Content-Encoding"] == "gzip"
            etag = response.headers["ETag"]
            assert gzip.decompress(await response.read()) == (STATIC / "app.js").read_bytes()
        async with session.get(url, headers={"If-None-Match": etag}) as response:
            assert response.status == 304
        async with session.head(url) as response:
            assert response.status == 200 and await response.read() == b""


@pytest.mark.parametrize(("if_none_match", "status"), [
    ("*", 304), ('W/"x", *', 304), ('"other"', 200), ('"a", "b"', 200)])
async def test_if_none_match_star_matches_any_representation(
        server: TestServer, if_none_match: str, status: int) -> None:
    """RFC 9110 13.1.2: ``*`` matches whatever representation exists, so a GET gets 304."""
    async with aiohttp.ClientSession() as session, session.get(
            server.make_url("/console/app.js"), headers={"If-None-Match": if_none_match}) as r:
        assert r.status == status


async def test_a_weak_etag_matches_for_if_none_match(server: TestServer) -> None:
    url = server.make_url("/console/app.js")
    async with aiohttp.ClientSession() as session:
        async with session.get(url) as response:
            etag = response.headers["ETag"]
        async with session.get(url, headers={"If-None-Match": f'"x", W/{etag}'}) as response:
            assert response.status == 304


@pytest.mark.parametrize(("accept", "gzipped"), [
    ("gzip;q=0", False), ("gzip; q=0.0, identity", False), ("*;q=0", False),
    ("br, gzip;q=0", False), ("gzip;q=0.5", True), ("*", True), ("x-gzip", True),
    ("GZIP;Q=1", True), ("gzip;q=nonsense", False), ("*, gzip;q=0", False),
    ("identity", False)])
async def test_gzip_only_when_its_q_value_is_above_zero(
        server: TestServer, accept: str, gzipped: bool) -> None:
    async with aiohttp.ClientSession(auto_decompress=False) as session, session.get(
            server.make_url("/console/app.js"), headers={"Accept-Encoding": accept}) as r:
        assert ("Content-Encoding" in r.headers) is gzipped, r.headers
        body = await r.read()
    assert (gzip.decompress(body) if gzipped else body) == (STATIC / "app.js").read_bytes()


@pytest.mark.parametrize("target", [
    "/console/../daemon/app.py", "/console/%2e%2e/__init__.py", "/console/..%2f__init__.py",
    "/console/static/app.js", "/console/", "/console", "/index.html", "/console/app.js/",
    "/console/APP.JS", "/console/app.js%00", "//etc/passwd", "/console/__init__.py",
    "/console/../../../../etc/passwd", "/console/index.html", "/console/%2e%2e",
    "/console/..", "/console/app.js%2f..%2f__init__.py", "/console/.%2e/static/app.js",
])
async def test_nothing_outside_the_table_is_served(server: TestServer, target: str) -> None:
    status, body = await raw_get(server.port, target)  # type: ignore[arg-type]
    assert status == 404, (target, body[:200])


def test_the_page_is_open_when_reads_need_the_token(tmp_path: Path) -> None:
    toml = '[security]\ntoken = "console-t0ken"\nread_requires_token = true\n'
    daemon = DaemonSubprocess(tmp_path, toml).start(wait_ready=False)
    try:
        status, body = wait_for(lambda: _answer(daemon, "/"), "the console page", within_s=20)
        assert status == 200 and "<title>arbiterd console</title>" in body
        assert daemon.get("/api/health")[0] == 401
        assert daemon.get("/api/health", token="console-t0ken")[0] == 200
    finally:
        daemon.__exit__()


def _answer(daemon: DaemonSubprocess, path: str) -> tuple[int, object] | None:
    try:
        return daemon.get(path, timeout=1.0)
    except OSError:
        return None


def test_the_console_can_be_turned_off(tmp_path: Path) -> None:
    with DaemonSubprocess(tmp_path, env={"ARBITERD_HTTP_CONSOLE": "false"}) as daemon:
        assert daemon.get("/")[0] == 404
        assert daemon.get("/console/app.js")[0] == 404
