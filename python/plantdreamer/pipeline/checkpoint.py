"""Resumable checkpoints of a generation run (``OUT/checkpoint.pt``), written atomically."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from plantdreamer.atomic import _umask  # noqa: F401  (tests check the file mode with it)
from plantdreamer.checkpoint_io import read_checkpoint, write_checkpoint
from plantdreamer.errors import CheckpointError

CHECKPOINT_NAME = "checkpoint.pt"
FORMAT_VERSION = 2  # 2: nested config sections, plain data only (weights_only loads)


def save_checkpoint(out_dir: Path, state: dict[str, Any]) -> Path:
    path = Path(out_dir) / CHECKPOINT_NAME
    write_checkpoint(path, {"format": FORMAT_VERSION, **state})
    return path


def load_checkpoint(out_dir: Path) -> dict[str, Any]:
    path = Path(out_dir) / CHECKPOINT_NAME
    state = read_checkpoint(path)
    if state.get("format") != FORMAT_VERSION:
        raise CheckpointError(f"{path}: not a plantdreamer checkpoint of format {FORMAT_VERSION}")
    return state
