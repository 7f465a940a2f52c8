"""The exceptions plantdreamer raises on purpose, every one importable from ``plantdreamer``.

The base classes are defined by the native module so that Rust errors cross the boundary
at one place (``crates/pyplant/src/errors.rs``); Python-only failures subclass them here.
Operating-system problems stay Python built-ins (``FileNotFoundError``, ``PermissionError``).
A stop asked for by Ctrl-C or SIGTERM is a ``KeyboardInterrupt`` (``RunInterrupted``,
``DatasetStopped``), so code that stops on Ctrl-C stops on these too. Torch-free: the
command line and the API raise them before torch is imported.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from plantdreamer._core import InputError, PlantDreamerError, PlyError

__all__ = [
    "CheckpointError",
    "DatasetStopped",
    "InputError",
    "ModelNotFoundError",
    "PlantDreamerError",
    "PlantsFailed",
    "PlyError",
    "PlyWarning",
    "RunInterrupted",
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


class PlantsFailed(PlantDreamerError):
    """Plants of a run failed; ``done`` are the others' results (``PlantResult``), written."""

    def __init__(self, message: str, done: list[Any]) -> None:
        super().__init__(message)
        self.done = done


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM during a run; a checkpoint at ``step`` was written before
    stopping (``resume`` continues from it). ``out_dir`` is the folder to resume;
    ``results`` (filled by the run's entry) says where each of its plants stood."""

    def __init__(self, step: int, out_dir: Path) -> None:
        super().__init__(f"interrupted at step {step}")
        self.step, self.out_dir = step, out_dir
        self.results: list[Any] = []


class DatasetStopped(KeyboardInterrupt):
    """Ctrl-C or SIGTERM stopped a dataset run; ``report`` (a ``DatasetReport``) says what
    it left. Running plants wrote their checkpoints: the same call again finishes them."""

    def __init__(self, report: Any) -> None:
        super().__init__()
        self.report = report
