# Prometheus text exposition of health, latency and component counters.
from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

from prometheus_client import CollectorRegistry, generate_latest

STATUS_VALUE = {"ok": 0, "degraded": 1, "error": 2}


def prometheus_text(health: dict[str, Any], latency: dict[str, Any],
                    registry: CollectorRegistry) -> str:
    """The latency histograms (prometheus_client) followed by health and component values."""
    return generate_latest(registry).decode() + _health_text(health, latency)


def _health_text(health: dict[str, Any], latency: dict[str, Any]) -> str:
    lines = [
        "# HELP arbiterd_up 1 while the daemon serves.",
        "# TYPE arbiterd_up gauge",
        "arbiterd_up 1",
        "# HELP arbiterd_status Overall health: 0 ok, 1 degraded, 2 error.",
        "# TYPE arbiterd_status gauge",
        f"arbiterd_status {STATUS_VALUE.get(health['status'], 2)}",
        "# HELP arbiterd_uptime_seconds Seconds since the daemon started.",
        "# TYPE arbiterd_uptime_seconds gauge",
        f"arbiterd_uptime_seconds {health['uptime_s']}",
        "# HELP arbiterd_ticks_total Control ticks run.",
        "# TYPE arbiterd_ticks_total counter",
        f"arbiterd_ticks_total {latency['tick']['count']}",
        "# HELP arbiterd_late_ticks_total Control ticks that started late ([control] "
        "late_tick_ms).",
        "# TYPE arbiterd_late_ticks_total counter",
        f"arbiterd_late_ticks_total {latency['tick']['late']}",
        "# HELP arbiterd_component_status Each component's health: 0 ok, 1 degraded, 2 error.",
        "# TYPE arbiterd_component_status gauge",
    ]
    values = ["# HELP arbiterd_component_value Each number of each component's health "
              "(nested keys joined by _).",
              "# TYPE arbiterd_component_value gauge"]
    for name, component in health["components"].items():
        lines.append(f'arbiterd_component_status{{component="{name}"}} '
                     f'{STATUS_VALUE.get(component.get("status", "error"), 2)}')
        for key, value in _numbers(component):
            values.append(f'arbiterd_component_value{{component="{name}",key="{key}"}} {value}')
    return "\n".join(lines + values) + "\n"


def _numbers(data: dict[str, Any], prefix: str = "") -> Iterator[tuple[str, float]]:
    for key, value in data.items():
        name = re.sub(r"[^a-zA-Z0-9_]", "_", f"{prefix}{key}")
        if isinstance(value, bool):
            yield name, int(value)
        elif isinstance(value, int | float):
            yield name, value
        elif isinstance(value, dict):
            yield from _numbers(value, name + "_")
