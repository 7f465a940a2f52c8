"""Presets: named sets of config values, applied before the user's own options.

- ``plantdreamer`` (the default): ``GenerateConfig``'s own defaults, nothing overridden.
- ``released``: the authors' released code at every step where it differs from ours.
- ``paper``: the paper's stated values where they differ from ours.

``docs/fidelity.md`` gives each step with the three values and the reason for ours. Every
key here is a setting's one name (``plantdreamer generate --help``), so any of them can still
be set on its own.
"""

from __future__ import annotations

from typing import Any

from plantdreamer.errors import InputError
from plantdreamer.guidance.config import (
    PAPER_PROMPT_TEMPLATE,
    RELEASED_NEGATIVE_PROMPT,
    RELEASED_PROMPT_TEMPLATE,
)
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.settings import canonical

PRESETS: dict[str, dict[str, Any]] = {
    "plantdreamer": {},
    "released": {
        "negative-prompt": RELEASED_NEGATIVE_PROMPT,
        "prompt-template": RELEASED_PROMPT_TEMPLATE,
        # Their CFG is eps_text + s (eps_text - eps_uncond) with s = 100: ours with s + 1.
        "guidance-scale": 101.0,
        "schedule": "released",
        "depth-rule": "released",
        "depth-size": "render",
        "control-resize": "nearest",
        "network-dtype": "float32",
        "cull-threshold": 7.0,
        "cull-volume": "double-exp",
        "cull-offset": 1,
        "densify-split-std": 0.5,
        "densify-cap-rule": "random",
        "densify-prune-screen-px": 1000.0,
        "points": 300_000,
        "mesh-sor": True,
        "sor-after-voxel": True,
        "init-scale": "rms",
        "init-shape": "sphere",
        "elevation-sampling": "mixed-full",
        "structures": "released",
        "erosion-distance": "c2w-norm",
        "downsample-tolerance": 0.25,
    },
    "paper": {
        "prompt-template": PAPER_PROMPT_TEMPLATE,
        "schedule": "paper",
        "cull-threshold": 3.0,
        "cull-volume": "log",
        "points": 100_000,
        "sor-after-voxel": False,
    },
}


def resolve_config(
    preset: str = "plantdreamer",
    options: dict[str, Any] | None = None,
    base: dict[str, Any] | None = None,
) -> GenerateConfig:
    """The config of ``preset`` with ``options`` (the user's explicit settings by name) on
    top; ``base`` (settings under the preset, e.g. the CLI's defaults) fills the rest, else
    the dataclass defaults do."""
    if preset not in PRESETS:
        raise InputError(f"unknown preset {preset!r}: use one of {', '.join(PRESETS)}")
    options = {canonical(k): v for k, v in (options or {}).items()}
    if options.pop("preset", preset) != preset:
        raise InputError("two different presets given")
    values = {**(base or {}), **PRESETS[preset], **options, "preset": preset}
    return GenerateConfig.from_settings(values)
