"""plantdreamer: realistic 3D Gaussian Splatting plants from L-Systems and point clouds."""

from __future__ import annotations

from typing import Any

from plantdreamer import thread_policy

# Before anything imports torch: its OpenMP runtime reads the policy once, when loaded.
thread_policy.settle()

from plantdreamer import _core  # noqa: E402
from plantdreamer.errors import (  # noqa: E402
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
