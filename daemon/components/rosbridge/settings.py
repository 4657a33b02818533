# [rosbridge]: the WebSocket server's address and every per-client budget.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option


@dataclass(frozen=True)
class RosbridgeSettings(SectionSettings, section="rosbridge"):
    """The [rosbridge] section, read once (keys with dots as underscores)."""

    enabled: bool = option(True, "serve the rosbridge v2 WebSocket")
    host: str = option("0.0.0.0", "rosbridge listen address")
    port: int = option(9090, "rosbridge listen port", minval=1, maxval=65535)
    max_clients: int = option(32, "most simultaneous WebSocket clients", minval=1, maxval=1024)
    max_connections: int = option(256, "most open TCP connections to the port, WebSocket or not "
                                  "yet; one more closes the oldest that has not completed its "
                                  "upgrade request (keep it well under LimitNOFILE)", minval=4,
                                  maxval=65536)
    handshake_timeout_s: float = option(10.0, "close a connection that has not sent a complete "
                                        "upgrade request (request line and headers) this long "
                                        "after it opened, s (slowloris)", above=0.0, maxval=3600.0)
    reserved_clients: int = option(4, "of max_clients, slots only clients with the token may take "
                                   "(when a token is configured)", minval=0, maxval=1024)
    max_message_bytes: int = option(1048576, "largest accepted incoming message (one frame, or "
                                    "one message joined from fragments), bytes", minval=1024,
                                    maxval=64 * 1048576)
    max_readonly_message_bytes: int = option(16384, "largest incoming message from a client that "
                                             "may not publish (no valid token while one is "
                                             "configured): one frame, or one message joined from "
                                             "fragments, bytes", minval=1024, maxval=64 * 1048576)
    idle_timeout: float = option(60.0, "close a connection without the token that has sent "
                                 "nothing and set nothing up (no subscription, topic or service) "
                                 "for this long, s (0 = never)", minval=0.0, maxval=86400.0)
    ops_per_second: float = option(1000.0, "requests one client may send per second, sustained",
                                   above=0.0, maxval=1e9)
    ops_burst: int = option(2000, "requests one client may send at once above the sustained rate",
                            minval=1, maxval=1_000_000_000)
    max_topics_per_client: int = option(100, "topics one client may advertise", minval=1,
                                        maxval=100_000)
    max_subscriptions_per_client: int = option(256, "subscriptions one client may hold (each "
                                               "subscribe id counts)", minval=1, maxval=100_000)
    max_services_per_client: int = option(32, "services one client may advertise", minval=1,
                                          maxval=10_000)
    max_pending_calls_per_client: int = option(64, "calls of one client waiting for another "
                                               "client's answer", minval=1, maxval=100_000)
    call_timeout: float = option(30.0, "a call forwarded to a client-provided service fails after "
                                 "this long; also the longest 'timeout' a call may ask for, s",
                                 above=0.0, maxval=3600.0)
    max_fragment_sets_per_client: int = option(8, "fragmented incoming messages one client may "
                                               "have unfinished", minval=1, maxval=1024)
    max_fragment_bytes_per_client: int = option(2 * 1048576, "bytes of unfinished incoming "
                                                "fragments one client may hold, all sets together "
                                                "(UTF-8, plus 64 per fragment)", minval=1024,
                                                maxval=256 * 1048576)
    max_fragments_per_message: int = option(100_000, "most fragments of one message, incoming "
                                            "('total') or outgoing (fragment_size)", minval=1,
                                            maxval=100_000_000)
    max_queue_length: int = option(100, "largest queue_length a subscription may ask for", minval=1,
                                   maxval=100_000)
    fragments_per_second: float = option(20_000.0, "outgoing fragments per second, all clients "
                                         "together (each costs CPU on the robot's event loop)",
                                         above=0.0, maxval=1e9)
