# The network side of tests: free local ports and a one-call JSON HTTP client.
from __future__ import annotations

import itertools
import json
import os
import random
import socket
import urllib.error
import urllib.request
from typing import Any

#: each pytest-xdist worker takes ports from a block of its own, below the kernel's ephemeral
#: range: a port one worker chose is never the one another worker's daemon binds meanwhile
PORT_BLOCK = 5000
_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:]
_FIRST = 10000 + PORT_BLOCK * (int(_WORKER) % 4 if _WORKER.isdigit() else 0)
_NEXT = itertools.count(random.randrange(PORT_BLOCK))


def free_port() -> int:
    """A local port free now, from this test process's own block (see PORT_BLOCK)."""
    for _ in range(PORT_BLOCK):
        port = _FIRST + next(_NEXT) % PORT_BLOCK
        with socket.socket() as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise OSError(f"no free port in {_FIRST}-{_FIRST + PORT_BLOCK - 1}")


def http(method: str, url: str, body: Any = None, *, token: str | None = None,
         raw: bytes | None = None, content_type: str = "application/json",
         timeout: float = 5.0) -> tuple[int, Any]:
    """One HTTP request; returns (status, parsed JSON or text)."""
    data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
    request = urllib.request.Request(url, data=data, method=method)
    if data is not None:
        request.add_header("Content-Type", content_type)
    if token:
        request.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(request, timeout=timeout) as response:
            return response.status, _decode(response.read())
    except urllib.error.HTTPError as exc:
        return exc.code, _decode(exc.read())


def _decode(payload: bytes) -> Any:
    try:
        return json.loads(payload)
    except ValueError:
        return payload.decode(errors="replace")
