"""Checkpoint files, written and read one way for every run (generation and LoRA training).

Written atomically (``plantdreamer.atomic``). Read with ``torch.load(weights_only=True)``,
which runs no code from the file, so a checkpoint holds only tensors, dicts, lists, tuples,
numbers, strings and None.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from plantdreamer.atomic import atomic_write
from plantdreamer.errors import CheckpointError


def write_checkpoint(path: Path, state: dict[str, Any]) -> None:
    atomic_write(path, lambda tmp: torch.save(state, tmp))


def read_checkpoint(path: Path) -> dict[str, Any]:
    """The checkpoint's dict; CheckpointError if the file is missing, corrupt or not a dict."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"no checkpoint to resume from: {path} does not exist")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a corrupt file
        raise CheckpointError(f"{path}: cannot read checkpoint ({exc})") from exc
    if not isinstance(state, dict):
        raise CheckpointError(f"{path}: not a checkpoint (holds {type(state).__name__})")
    return state
