# Any answer, not only a download, is cut off when its client stops reading for send_timeout_s.
from __future__ import annotations

from aiohttp import web

from base.options import defaults
from daemon.components.http.component import HttpServer
from daemon.components.http.settings import HttpSettings
from daemon.security import Security
from tests.support.hostile import never_reading
from tests.support.net import free_port
from tests.support.wait import eventually


async def test_a_big_json_answer_to_a_client_that_never_reads_lets_its_slot_go() -> None:
    """Found by the hostile contract test: a never-reading client of a big JSON answer (a
    map) held its connection slot for as long as it stayed connected (aiohttp waits for the
    socket to drain, with no time limit)."""
    port = free_port()
    server = HttpServer(HttpSettings.from_values(defaults(HttpSettings.OPTIONS) | {
        "host": "127.0.0.1", "port": port, "send_timeout_s": 0.5, "idle_timeout_s": 1.0}),
        Security(""))

    async def big(request: web.Request) -> web.Response:
        return web.json_response({"data": "a" * 4_000_000})

    server.add_route("GET", "/api/big", big, access="read")
    await server.start()
    clients = await never_reading(port, "GET", "/api/big", "", 4)
    try:
        await eventually(lambda: server.health().values["connections"] == 0,
                         "the never-reading clients let go")
    finally:
        for sock in clients:
            sock.close()
        await server.stop()
