# RPLIDAR: wire protocol, revolution assembly, device manager, daemon component and CLI.
from __future__ import annotations
