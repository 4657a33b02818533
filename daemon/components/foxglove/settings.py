# [foxglove]: the Foxglove WebSocket server's address and every per-client budget.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option


@dataclass(frozen=True)
class FoxgloveSettings(SectionSettings, section="foxglove"):
    """The [foxglove] section, read once (keys with dots as underscores)."""

    enabled: bool = option(False, "serve the Foxglove WebSocket protocol (Foxglove's and "
        "Lichtblick's own connection; subprotocols foxglove.sdk.v1 and foxglove.websocket.v1)")
    host: str = option("0.0.0.0", "Foxglove WebSocket listen address")
    port: int = option(8765, "Foxglove WebSocket listen port", minval=1, maxval=65535)
    max_clients: int = option(16, "most simultaneous Foxglove clients", minval=1, maxval=1024)
    reserved_clients: int = option(2,
        "of max_clients, slots only clients with the token may take (when a token is configured)",
        minval=0, maxval=1024)
    max_connections: int = option(64, "most open TCP connections to the port, upgraded or not yet",
        minval=4, maxval=65536)
    handshake_timeout_s: float = option(10.0, "close a connection that has not sent a complete "
        "upgrade request this long after it opened, s", above=0.0, maxval=3600.0)
    max_message_bytes: int = option(1048576,
        "largest accepted incoming frame from a client with drive access, bytes", minval=1024,
        maxval=64 * 1048576)
    max_readonly_message_bytes: int = option(16384,
        "largest incoming frame from a client without the token (when one is configured), bytes",
        minval=1024, maxval=64 * 1048576)
    frames_per_second: float = option(1000.0,
        "frames one client may send per second, sustained (over it, reading pauses)", above=0.0,
        maxval=1e9)
    frames_burst: int = option(2000, "frames one client may send at once above the sustained rate",
        minval=1, maxval=1_000_000_000)
    queue_messages: int = option(100, "messages kept per subscription of an event topic (logs, "
        "commands) for a client that reads slowly; state topics keep only their latest", minval=1,
        maxval=100_000)
    max_subscriptions_per_client: int = option(256, "subscriptions one client may hold", minval=1,
        maxval=100_000)
    max_channels_per_client: int = option(32, "channels one client may advertise to publish on",
        minval=1, maxval=10_000)
