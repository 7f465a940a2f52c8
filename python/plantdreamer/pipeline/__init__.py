"""The generation pipeline: point cloud -> initial Gaussians -> guided optimisation -> outputs.

Names load on first use, so ``plantdreamer.pipeline.config`` (read by the CLI at start-up)
does not import torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from plantdreamer.pipeline.config import GenerateConfig
    from plantdreamer.pipeline.plants import generate_plants
    from plantdreamer.pipeline.presets import PRESETS, resolve_config
    from plantdreamer.pipeline.run import RunInterrupted, RunResult, generate
    from plantdreamer.pipeline.step.options import StepOptions

__all__ = [
    "PRESETS",
    "GenerateConfig",
    "RunInterrupted",
    "RunResult",
    "StepOptions",
    "generate",
    "generate_plants",
    "resolve_config",
]

_MODULES = {
    "GenerateConfig": "plantdreamer.pipeline.config",
    "PRESETS": "plantdreamer.pipeline.presets",
    "resolve_config": "plantdreamer.pipeline.presets",
    "RunInterrupted": "plantdreamer.pipeline.run",
    "RunResult": "plantdreamer.pipeline.run",
    "generate": "plantdreamer.pipeline.run",
    "generate_plants": "plantdreamer.pipeline.plants",
    "StepOptions": "plantdreamer.pipeline.step.options",
}


def __getattr__(name: str) -> Any:
    if name not in _MODULES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_MODULES[name]), name)
