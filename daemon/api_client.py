# The running daemon's HTTP API as the command-line tools call it: JSON in, JSON out, and
# failures said the way a user can act on.
from __future__ import annotations

import json
import urllib.error
import urllib.request
from typing import Any

TIMEOUT_S = 10.0


def call_api(base: str, token: str, method: str, path: str,
             body: dict[str, Any] | None = None) -> dict[str, Any]:
    """``method`` ``path`` on the daemon at ``base`` with ``body`` as JSON (None: no body);
    its JSON answer. Raises urllib's HTTPError (a refusal) or URLError/OSError (no answer)."""
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(f"{base}{path}", method=method, data=data,
                                     headers={"Content-Type": "application/json"})
    if token:
        request.add_header("Authorization", f"Bearer {token}")
    with urllib.request.urlopen(request, timeout=TIMEOUT_S) as response:
        answer: dict[str, Any] = json.load(response)
    return answer


def api_failure(base: str, exc: OSError) -> str:
    """What went wrong calling the daemon: its refusal with its own reason, or why nothing
    answered."""
    if isinstance(exc, urllib.error.HTTPError):
        try:
            error = json.load(exc).get("error", exc.reason)
        except ValueError:
            error = exc.reason
        return f"the daemon refused ({exc.code}): {error}"
    return f"cannot reach {base}: {getattr(exc, 'reason', exc)}"
