"""Versions of Python and the packages a run depends on, and the CPU it ran on, recorded in
its outputs."""

from __future__ import annotations

import importlib.metadata
import platform
from collections.abc import Sequence
from pathlib import Path

RUN_PACKAGES = ("plantdreamer", "torch", "numpy", "diffusers", "transformers", "peft")


def package_versions(packages: Sequence[str] = RUN_PACKAGES) -> dict[str, str | None]:
    """``{"python": ..., package: version or None when it is not installed}``."""
    versions: dict[str, str | None] = {"python": platform.python_version()}
    for package in packages:
        try:
            versions[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            versions[package] = None
    return versions


def cpu_model() -> str:
    """The CPU's marketing name (Linux /proc/cpuinfo), else what `platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"
