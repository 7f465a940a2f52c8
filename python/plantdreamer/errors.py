"""The exceptions plantdreamer raises on purpose.

The base classes are defined by the native module so that Rust errors cross the boundary
at one place (``crates/pyplant/src/errors.rs``); Python-only failures subclass them here.
Operating-system problems stay Python built-ins (``FileNotFoundError``, ``PermissionError``).
"""

from __future__ import annotations

from plantdreamer._core import InputError, PlantDreamerError, PlyError

__all__ = [
    "CheckpointError",
    "InputError",
    "ModelNotFoundError",
    "PlantDreamerError",
    "PlyError",
    "PlyWarning",
]


class PlyWarning(UserWarning):
    """A PLY file was read, but part of it after the vertex element was ignored.

    Raised as a warning (``warnings.warn``) by the readers in ``plantdreamer.io``: the file
    has extra rows at the end (as MeshLab writes), or an element after the vertices (faces)
    is truncated or malformed. The message names the file and what was ignored. Pass
    ``strict=True`` to the reader to get a :class:`PlyError` instead.
    """


class ModelNotFoundError(PlantDreamerError):
    """Model weights (Stable Diffusion, ControlNet, LoRA) are not available locally.

    The message names what was looked for and how to provide it.
    """


class CheckpointError(PlantDreamerError):
    """A checkpoint is missing, corrupt, or belongs to a different run configuration."""
