"""The generation pipeline: point cloud -> initial Gaussians -> guided optimisation -> outputs.

Names load on first use, so ``plantdreamer.pipeline.settings.config`` (read by the CLI at start-up)
does not import torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from plantdreamer.errors import PlantsFailed, RunInterrupted
    from plantdreamer.pipeline.runs.entry import generate_plants
    from plantdreamer.pipeline.runs.layout import FolderPerPlant, GivenFolders, PlantAlone
    from plantdreamer.pipeline.runs.results import PlantResult
    from plantdreamer.pipeline.settings.config import GenerateConfig
    from plantdreamer.pipeline.settings.presets import PRESETS, resolve_config
    from plantdreamer.pipeline.step.options import StepOptions

__all__ = [
    "PRESETS",
    "FolderPerPlant",
    "GenerateConfig",
    "GivenFolders",
    "PlantAlone",
    "PlantResult",
    "PlantsFailed",
    "RunInterrupted",
    "StepOptions",
    "generate_plants",
    "resolve_config",
]

_MODULES = {
    "GenerateConfig": "plantdreamer.pipeline.settings.config",
    "PRESETS": "plantdreamer.pipeline.settings.presets",
    "resolve_config": "plantdreamer.pipeline.settings.presets",
    "generate_plants": "plantdreamer.pipeline.runs.entry",
    "FolderPerPlant": "plantdreamer.pipeline.runs.layout",
    "GivenFolders": "plantdreamer.pipeline.runs.layout",
    "PlantAlone": "plantdreamer.pipeline.runs.layout",
    "PlantResult": "plantdreamer.pipeline.runs.results",
    "PlantsFailed": "plantdreamer.errors",
    "RunInterrupted": "plantdreamer.errors",
    "StepOptions": "plantdreamer.pipeline.step.options",
}


def __getattr__(name: str) -> Any:
    if name not in _MODULES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_MODULES[name]), name)
