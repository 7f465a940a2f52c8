"""Resumable checkpoints of a generation run (``OUT/checkpoint.pt``), written atomically."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from plantdreamer.atomic import _umask  # noqa: F401  (tests check the file mode with it)
from plantdreamer.checkpoint_io import read_checkpoint, write_checkpoint
from plantdreamer.errors import CheckpointError

CHECKPOINT_NAME = "checkpoint.pt"
# 2: nested config sections, plain data only (weights_only loads);
# 3: the config records init_shape (format 2 runs began from spheres, the default is now discs,
#    so resuming one would record a shape its model was not made with).
FORMAT_VERSION = 3


def save_checkpoint(out_dir: Path, state: dict[str, Any]) -> Path:
    path = Path(out_dir) / CHECKPOINT_NAME
    write_checkpoint(path, {"format": FORMAT_VERSION, **state})
    return path


def load_checkpoint(out_dir: Path) -> dict[str, Any]:
    path = Path(out_dir) / CHECKPOINT_NAME
    state = read_checkpoint(path)
    found = state.get("format")
    if found != FORMAT_VERSION:
        what = f"format {found}" if isinstance(found, int) else "not a plantdreamer checkpoint"
        raise CheckpointError(
            f"{path}: {what}; this plantdreamer resumes format {FORMAT_VERSION} only "
            "(start the run again with --overwrite)"
        )
    return state
