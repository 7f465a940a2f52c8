"""Presets: named sets of config values, applied before the user's own options.

- ``plantdreamer`` (the default): ``GenerateConfig``'s own defaults, nothing overridden.
- ``released``: the authors' released code at every step where it differs from ours.
- ``paper``: the paper's stated values where they differ from ours.

``docs/fidelity.md`` gives each step with the three values and the reason for ours. Every
value here is a config field (nested configs as nested dicts), so any of them can still be
set on its own.
"""

from __future__ import annotations

from typing import Any

from plantdreamer.errors import InputError
from plantdreamer.guidance.config import (
    PAPER_PROMPT_TEMPLATE,
    RELEASED_NEGATIVE_PROMPT,
    RELEASED_PROMPT_TEMPLATE,
)
from plantdreamer.pipeline.config import GenerateConfig

PRESETS: dict[str, dict[str, Any]] = {
    "plantdreamer": {},
    "released": {
        "negative_prompt": RELEASED_NEGATIVE_PROMPT,
        "prompt_template": RELEASED_PROMPT_TEMPLATE,
        # Their CFG is eps_text + s (eps_text - eps_uncond) with s = 100: ours with s + 1.
        "guidance_scale": 101.0,
        "schedule": "released",
        "depth_rule": "released",
        "control_resize": "nearest",
        "network_dtype": "float32",
        "cull": {"threshold": 7.0, "volume": "double-exp", "offset": 1},
        "densify": {"split_std": 0.5, "cap_rule": "random", "prune_screen_px": 1000.0},
        "n_points": 300_000,
        "mesh_sor": True,
        "sor_after_voxel": True,
        "init_scale": "rms",
        "init_shape": "sphere",
        "elevation_sampling": "mixed-full",
        "structures": "released",
        "erosion_distance": "c2w-norm",
        "downsample_tolerance": 0.25,
    },
    "paper": {
        "prompt_template": PAPER_PROMPT_TEMPLATE,
        "schedule": "paper",
        "cull": {"threshold": 3.0, "volume": "log"},
        "n_points": 100_000,
        "sor_after_voxel": False,
    },
}


def merge(base: dict[str, Any], top: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``top``'s values on top, nested dicts merged key by key."""
    out = dict(base)
    for key, value in top.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def resolve_config(
    preset: str = "plantdreamer",
    options: dict[str, Any] | None = None,
    base: dict[str, Any] | None = None,
) -> GenerateConfig:
    """The config of ``preset`` with ``options`` (the user's explicit settings, nested like
    ``GenerateConfig.to_dict()``) on top; ``base`` (values under the preset, e.g. the CLI's
    defaults) fills the rest, else the dataclass defaults do."""
    if preset not in PRESETS:
        raise InputError(f"unknown preset {preset!r}: use one of {', '.join(PRESETS)}")
    options = dict(options or {})
    if options.pop("preset", preset) != preset:
        raise InputError("two different presets given")
    values = merge(merge(base or {}, PRESETS[preset]), options)
    return GenerateConfig.from_dict({**values, "preset": preset})
