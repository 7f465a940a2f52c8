"""plantdreamer: realistic 3D Gaussian Splatting plants from L-Systems and point clouds."""

from __future__ import annotations

from typing import Any

from plantdreamer import thread_policy

# Before anything imports torch: its OpenMP runtime reads the policy once, when loaded.
thread_policy.settle()

from plantdreamer import _core  # noqa: E402
from plantdreamer.errors import (  # noqa: E402
    CheckpointError,
    DatasetStopped,
    InputError,
    ModelNotFoundError,
    PlantDreamerError,
    PlantsFailed,
    PlyError,
    PlyWarning,
    RunInterrupted,
)

__version__: str = _core.__version__

__all__ = [
    "CheckpointError",
    "DatasetResult",
    "DatasetStopped",
    "GenerateConfig",
    "GeneratedPlant",
    "InputError",
    "ModelNotFoundError",
    "PlantDreamerError",
    "PlantsFailed",
    "PlyError",
    "PlyWarning",
    "RunInterrupted",
    "SceneResult",
    "__version__",
    "generate",
    "make_dataset",
    "make_scene",
    "rasterization",
]


# Names loaded on first use, so `import plantdreamer` (and the CLI) stay light: the Python
# API (plantdreamer.api) and the torch-backed rasterizer.
_LAZY = {
    "DatasetResult": "plantdreamer.api",
    "GenerateConfig": "plantdreamer.pipeline.settings.config",
    "GeneratedPlant": "plantdreamer.api",
    "generate": "plantdreamer.api",
    "make_dataset": "plantdreamer.api",
    "make_scene": "plantdreamer.scenes",
    "SceneResult": "plantdreamer.scenes",
    "rasterization": "plantdreamer.rasterizer",
}


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module 'plantdreamer' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(_LAZY[name]), name)
    globals()[name] = value
    return value
