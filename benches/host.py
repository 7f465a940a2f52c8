"""What machine a figure came from: the CPU model and the cores this process may use.

Figures of the CPU phases move with the host (two H100 machines differed by up to 1.6x),
so every report that mixes CPU and GPU work names both.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path


def cpu_model() -> str:
    """The CPU's marketing name (Linux /proc/cpuinfo), else what `platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def usable_cores() -> int:
    """Cores this process may run on (its affinity mask, e.g. a container's share)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def host_line() -> str:
    """One line naming the CPU and its cores, for a report's header."""
    return f"{cpu_model()}, {usable_cores()} usable cores ({os.cpu_count()} online)"
