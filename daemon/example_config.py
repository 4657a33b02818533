# Renders systemd/arbiterd.toml.example from the option tables, so every key is documented.
from __future__ import annotations

import sys
from typing import Any

from daemon.cli import _toml_value
from daemon.config import all_sections, section_options

HEADER = """\
# arbiterd configuration: /etc/arbiterd/arbiterd.toml
#
# Every key is listed with its default. Lines starting with '#' are comments: uncomment a key to
# change it. Unknown keys, wrong types and out-of-range values are errors that name the key.
# Any key can also be set from the environment as ARBITERD_<SECTION>_<KEY>, dots as
# underscores, e.g. ARBITERD_LIMITS_LINEAR_X_MAX_VELOCITY=0.5.
# Validate with:  arbiterd check --config /etc/arbiterd/arbiterd.toml
"""

# The values a Raspberry Pi robot starts from (everything else keeps its default).
PI_VALUES: dict[str, dict[str, Any]] = {
    "driver": {"type": "serial"},
    "lidar": {"enabled": True},
    "recorder": {"enabled": True},  # the service records; `run --sim` from a checkout does not
}


def render() -> str:
    out = [HEADER]
    for section in all_sections():
        options = section_options(section)
        set_here = PI_VALUES.get(section, {})
        out.append(f"[{section}]")
        for key, option in options.items():
            out.append(f"# {option.doc}")
            value = set_here.get(key, option.default)
            prefix = "" if key in set_here else "# "
            out.append(f"{prefix}{key} = {_toml_value(value)}")
        out.append("")
    return "\n".join(out)


if __name__ == "__main__":
    sys.stdout.write(render())
