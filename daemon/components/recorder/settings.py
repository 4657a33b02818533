# [recorder]: where the flight recorder writes, how big files get, how often it flushes.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option

RECORD_COMPRESSIONS = ("zstd", "lz4", "none")


@dataclass(frozen=True)
class RecorderSettings(SectionSettings, section="recorder", aliases=("record",)):
    """The [recorder] section, read once ([record] before the section took the component's
    name: still read, with a deprecation warning)."""

    enabled: bool = option(False, "record /odom, /tf, /scan, commands, latency reports, log lines "
                           "and health changes to MCAP files (the flight recorder)")
    directory: str = option("", "where the MCAP files go; '' = recordings/ in the service's state "
                            "directory ($STATE_DIRECTORY, /var/lib/arbiterd under systemd), else "
                            "in ~/.local/state/arbiterd")
    max_file_mb: float = option(64.0, "start a new file when the current one reaches this size, MB",
                                minval=1.0, maxval=4096.0)
    max_file_s: float = option(900.0, "start a new file when the current one covers this long, s",
                               minval=10.0, maxval=86400.0)
    max_total_mb: float = option(1024.0, "cap on all recordings together: the oldest files are "
                                 "deleted first, MB", minval=2.0, maxval=1048576.0)
    compression: str = option("zstd", "chunk compression", choices=RECORD_COMPRESSIONS)
    flush_interval_s: float = option(1.0, "chunks are closed and written at least this often: "
                                     "what a crash or power cut can lose, s", minval=0.05,
                                     maxval=1.0)
    queue_size: int = option(10000, "messages waiting for the writer thread; when full, new ones "
                             "are dropped and counted", minval=100, maxval=1000000)
