"""Training checkpoints of a LoRA run: save, find the latest, and check a resume fits.

A checkpoint holds everything that makes the next step the same as in an uninterrupted run:
the LoRA weights (PEFT layout), the optimiser and grad-scaler states, the random generator
state, the step and the loss history, plus the run's fingerprint (the settings a resumed run
must share). Files are ``OUT/checkpoints/step-000300.pt``; the ``keep`` newest are kept.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from plantdreamer.checkpoint_io import read_checkpoint, write_checkpoint
from plantdreamer.errors import CheckpointError

CHECKPOINT_DIR = "checkpoints"


def checkpoint_path(out: Path, step: int) -> Path:
    return out / CHECKPOINT_DIR / f"step-{step:06d}.pt"


def list_checkpoints(out: Path) -> list[Path]:
    folder = out / CHECKPOINT_DIR
    if not folder.is_dir():
        return []
    return sorted(folder.glob("step-*.pt"))


def save_checkpoint(out: Path, step: int, state: dict[str, Any], keep: int = 2) -> Path:
    path = checkpoint_path(out, step)
    write_checkpoint(path, state)
    for old in list_checkpoints(out)[:-keep]:
        old.unlink(missing_ok=True)
    return path


def load_checkpoint(path: Path) -> dict[str, Any]:
    state = read_checkpoint(path)
    missing = {"step", "lora", "optimizer", "generator", "losses", "fingerprint"} - set(state)
    if missing:
        raise CheckpointError(f"checkpoint {str(path)!r} lacks {sorted(missing)}")
    return state


def check_fingerprint(path: Path, saved: dict[str, Any], current: dict[str, Any]) -> None:
    """CheckpointError naming every setting that differs between the run and the checkpoint."""
    diffs = [
        f"{key}: checkpoint {saved.get(key)!r}, now {current.get(key)!r}"
        for key in sorted(set(saved) | set(current))
        if saved.get(key) != current.get(key)
    ]
    if diffs:
        raise CheckpointError(
            f"checkpoint {str(path)!r} belongs to a different run ({'; '.join(diffs)}); "
            "use the same settings, or a new --out folder to start afresh"
        )
