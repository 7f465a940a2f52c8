"""What machine a figure came from: the CPU model and the cores this process may use.

Figures of the CPU phases move with the host (two H100 machines differed by up to 1.6x),
so every report that mixes CPU and GPU work names both.
"""

from __future__ import annotations

import os

from plantdreamer.versions import cpu_model


def usable_cores() -> int:
    """Cores this process may run on (its affinity mask, e.g. a container's share)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def host_line() -> str:
    """One line naming the CPU and its cores, for a report's header."""
    return f"{cpu_model()}, {usable_cores()} usable cores ({os.cpu_count()} online)"
