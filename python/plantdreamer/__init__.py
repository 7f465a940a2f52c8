"""plantdreamer: realistic 3D Gaussian Splatting plants from L-Systems and point clouds."""

from __future__ import annotations

from typing import Any

from plantdreamer import _core
from plantdreamer.errors import (
    CheckpointError,
    InputError,
    ModelNotFoundError,
    PlantDreamerError,
    PlyError,
    PlyWarning,
)

__version__: str = _core.__version__

__all__ = [
    "CheckpointError",
    "InputError",
    "ModelNotFoundError",
    "PlantDreamerError",
    "PlyError",
    "PlyWarning",
    "__version__",
    "rasterization",
]


def __getattr__(name: str) -> Any:
    # torch-backed names load on first use so `import plantdreamer` (and the CLI) stay light.
    if name == "rasterization":
        from plantdreamer.rasterizer import rasterization

        globals()[name] = rasterization
        return rasterization
    raise AttributeError(f"module 'plantdreamer' has no attribute {name!r}")
