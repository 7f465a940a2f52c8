"""Diffusion guidance: score distillation (SDS) with Stable Diffusion + depth ControlNet + LoRA.

Names load on first use: importing ``plantdreamer.guidance.config`` (read by the CLI at
start-up) does not import torch; diffusers / transformers load when models are built.

- ``config``: ``SdsConfig``, the SDS settings and their defaults
- ``base``: the ``Guidance`` protocol, ``GuidanceOutput``, ``NoGuidance``, ``PhotometricGuidance``
- ``sds``: ``StableDiffusionDepthGuidance``
- ``schedules``: timestep schedules (paper, released code, user tables) and the clamp ramp
- ``prompts``: view-dependent prompts
- ``text``: the CLIP prompt-embedding cache
- ``depth``: depth-map cleaning and the per-pose ``DepthConditioner``
- ``models``: loading from the hub or local folders, ``ModelNotFoundError`` messages
- ``lora_weights``: species LoRA files
- ``tiny``: tiny random-weight models for tests and benchmarks
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from plantdreamer.guidance.base import (
        Guidance,
        GuidanceOutput,
        NoGuidance,
        PhotometricGuidance,
    )
    from plantdreamer.guidance.config import SdsConfig
    from plantdreamer.guidance.depth import DepthCleaning, DepthConditioner, clean_depth
    from plantdreamer.guidance.prompts import view_prompt
    from plantdreamer.guidance.schedules import TimestepSchedule, make_schedule
    from plantdreamer.guidance.sds import StableDiffusionDepthGuidance
    from plantdreamer.guidance.tiny import save_tiny_models, tiny_models

_MODULES = {
    "DepthCleaning": "depth",
    "DepthConditioner": "depth",
    "Guidance": "base",
    "GuidanceOutput": "base",
    "NoGuidance": "base",
    "PhotometricGuidance": "base",
    "SdsConfig": "config",
    "StableDiffusionDepthGuidance": "sds",
    "TimestepSchedule": "schedules",
    "clean_depth": "depth",
    "make_schedule": "schedules",
    "save_tiny_models": "tiny",
    "tiny_models": "tiny",
    "view_prompt": "prompts",
}

__all__ = [
    "DepthCleaning",
    "DepthConditioner",
    "Guidance",
    "GuidanceOutput",
    "NoGuidance",
    "PhotometricGuidance",
    "SdsConfig",
    "StableDiffusionDepthGuidance",
    "TimestepSchedule",
    "clean_depth",
    "make_schedule",
    "save_tiny_models",
    "tiny_models",
    "view_prompt",
]


def __getattr__(name: str) -> Any:
    if name not in _MODULES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_MODULES[name]}"), name)
