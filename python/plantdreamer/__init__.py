"""plantdreamer: realistic 3D Gaussian Splatting plants from L-Systems and point clouds."""

from __future__ import annotations

from plantdreamer import _core
from plantdreamer.errors import (
    CheckpointError,
    InputError,
    ModelNotFoundError,
    PlantDreamerError,
    PlyError,
)

__version__: str = _core.__version__

__all__ = [
    "CheckpointError",
    "InputError",
    "ModelNotFoundError",
    "PlantDreamerError",
    "PlyError",
    "__version__",
]
