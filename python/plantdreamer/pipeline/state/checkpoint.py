"""Resumable checkpoints of a generation run (``OUT/checkpoint.pt``), written atomically.

A checkpoint is a ``CheckpointRecord``: the config and ``RunState.state_dict()``, built (for
the trainer) and taken apart (for a resume) here only. The guidance's noise state is the
group's, not a plant's: it is saved once per trainer (``group_noise.py``). Older formats
still load where their contents carry over exactly (format 4's copy of the noise state in
every plant's checkpoint is read back from its plants); others fail with one line.

``PlantCheckpoints`` writes a plant's checkpoints (for the trainer) and reads them back (for a
resume), one object for both. Plants trained together write one after another, so a kill
between two writes would leave them at different steps; each therefore keeps its previous
checkpoint (``checkpoint.prev.pt``) until every plant has written the new one, and a resume
finds a step that every plant of the group can start from (``common_starts``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from plantdreamer.atomic import _umask  # noqa: F401  (tests check the file mode with it)
from plantdreamer.checkpoint_io import read_checkpoint, write_checkpoint
from plantdreamer.errors import CheckpointError, InputError
from plantdreamer.pipeline.state.run_outputs import CHECKPOINT_FILES, CHECKPOINT_NAME, PREVIOUS_NAME

if TYPE_CHECKING:
    from plantdreamer.pipeline.settings.config import GenerateConfig
    from plantdreamer.pipeline.state.run_state import RunState

# 2: nested config sections, plain data only (weights_only loads);
# 3: the config records init_shape (format 2 runs began from spheres, the default is now discs,
#    so resuming one would record a shape its model was not made with);
# 4: the config in sections (source, init, train, sds, density, outputs); density control's
#    state under "density". Format 3 converts exactly (each old key has one new name).
# 5: no noise state (the group's, in group_noise.py); format 4's loads with its copy.
FORMAT_VERSION = 5
_CONVERTS = (3,)
_READS = (4, FORMAT_VERSION)  # loaded as they are
# A format-4 checkpoint's entries of the guidance's noise generator (``noise_state``).
_NOISE_KEYS = ("guidance", "guidance_device")


@dataclass
class CheckpointRecord:
    """One plant's checkpoint: its settings (``config``, a resolved run's) and its run state
    (``RunState.state_dict()``); ``noise``: the guidance's noise state a format-4 file
    carried (None since: the group's noise is saved apart)."""

    config: GenerateConfig
    state: dict[str, Any]
    noise: dict[str, Any] | None = None

    @property
    def step(self) -> int:
        return int(self.state["step"])

    @classmethod
    def of(cls, config: GenerateConfig, state: RunState) -> CheckpointRecord:
        return cls(config, state.state_dict())

    def to_saved(self) -> dict[str, Any]:
        """The file's contents (format ``FORMAT_VERSION``, plain data and tensors)."""
        return {"config": self.config.to_dict(), **self.state}

    @classmethod
    def from_saved(cls, saved: dict[str, Any], path: Path) -> CheckpointRecord:
        """A loaded checkpoint file's record; CheckpointError when its config or step
        cannot be read."""
        from plantdreamer.pipeline.settings.config import GenerateConfig

        try:
            config = GenerateConfig.from_dict(saved["config"])
            config.validate()
            int(saved["step"])
        except (KeyError, TypeError, ValueError, InputError) as exc:
            raise CheckpointError(f"{path}: damaged checkpoint, bad config ({exc})") from exc
        noise = {k: saved[k] for k in _NOISE_KEYS if k in saved} or None
        state = {k: v for k, v in saved.items() if k not in ("format", "config", *_NOISE_KEYS)}
        return cls(config, state, noise)


def save_checkpoint(out_dir: Path, state: dict[str, Any]) -> Path:
    path = Path(out_dir) / CHECKPOINT_NAME
    write_checkpoint(path, {"format": FORMAT_VERSION, **state})
    return path


def load_checkpoint(out_dir: Path, name: str = CHECKPOINT_NAME) -> dict[str, Any]:
    path = Path(out_dir) / name
    state = read_checkpoint(path)
    found = state.get("format")
    if found in _CONVERTS:
        return _from_format_3(state, path)
    if found not in _READS:
        what = f"format {found}" if isinstance(found, int) else "not a plantdreamer checkpoint"
        raise CheckpointError(
            f"{path}: {what}; this plantdreamer resumes formats 3 to {FORMAT_VERSION} only "
            "(start the run again with --overwrite)"
        )
    return state


class PlantCheckpoints:
    """A plant folder's checkpoints: the trainer writes them, a resume reads them back."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)

    def write(self, record: CheckpointRecord) -> None:
        """The next checkpoint; the current one is kept as the previous until ``commit``."""
        current = self.folder / CHECKPOINT_NAME
        if current.is_file():
            os.replace(current, self.folder / PREVIOUS_NAME)
        save_checkpoint(self.folder, record.to_saved())

    def commit(self) -> None:
        """Every plant trained beside this one holds the new step: the previous one goes."""
        (self.folder / PREVIOUS_NAME).unlink(missing_ok=True)

    def starts(self) -> dict[int, str]:
        """The steps this folder can resume from, each with its file's name."""
        found: dict[int, str] = {}
        for name in CHECKPOINT_FILES:
            path = self.folder / name
            if path.is_file():
                found.setdefault(_step_of(path), name)
        return found

    def read(self, name: str = CHECKPOINT_NAME) -> CheckpointRecord:
        """The checkpoint in file ``name``, which becomes the folder's one checkpoint."""
        record = CheckpointRecord.from_saved(
            load_checkpoint(self.folder, name), self.folder / CHECKPOINT_NAME
        )
        if name == PREVIOUS_NAME:
            os.replace(self.folder / PREVIOUS_NAME, self.folder / CHECKPOINT_NAME)
        else:
            self.commit()
        return record

    def restore(self, cfg: GenerateConfig, record: CheckpointRecord) -> RunState:
        """The run state a checkpoint holds, for the run's ``cfg`` (the record's, with the
        changes a resume allows); CheckpointError when it is damaged."""
        from plantdreamer.pipeline.state.run_state import RunState

        try:
            return RunState.resumed(cfg, record.state)
        except (KeyError, TypeError, ValueError, IndexError, RuntimeError) as exc:
            raise damaged(self.folder / CHECKPOINT_NAME, exc) from exc


def damaged(path: Path, exc: BaseException) -> CheckpointError:
    return CheckpointError(
        f"{path}: damaged or incompatible checkpoint ({type(exc).__name__}: {exc})"
    )


def read_config(path: Path) -> GenerateConfig:
    """A checkpoint's config, read without loading its tensors (memory-mapped);
    CheckpointError when it cannot be read."""
    import torch

    try:
        saved = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except Exception:  # unreadable: read it the ordinary way for the one-line error
        saved = load_checkpoint(path.parent, path.name)
    if saved.get("format") in _CONVERTS:
        saved = _from_format_3(saved, path)
    return CheckpointRecord.from_saved(saved, path).config


def _step_of(path: Path) -> int:
    """A checkpoint's step, read without loading its tensors (memory-mapped)."""
    import torch

    try:
        step = torch.load(path, map_location="cpu", weights_only=True, mmap=True)["step"]
    except Exception:  # unreadable: read it the ordinary way for the one-line error
        step = load_checkpoint(path.parent, path.name)["step"]
    try:
        return int(step)
    except (TypeError, ValueError) as exc:
        raise damaged(path, exc) from exc


def common_starts(starts: dict[Any, dict[int, str]]) -> list[tuple[int | None, list[Any]]]:
    """Plants (by key) grouped by the step they resume from together, given each plant's
    ``PlantCheckpoints.starts``. Plants trained together hold their last common step (in
    the current or the previous file): the group resumes there, every plant on the same
    bits as a run never stopped. Plants that hold no common step (trained apart) form groups
    of their own, each at its own step; plants with no checkpoint start afresh (None)."""
    left = {key: steps for key, steps in starts.items() if steps}
    parts: list[tuple[int | None, list[Any]]] = []
    while left:
        step = min(max(steps) for steps in left.values())
        members = [key for key, steps in left.items() if step in steps]
        parts.append((step, members))
        for key in members:
            del left[key]
    fresh = [key for key, steps in starts.items() if not steps]
    return ([(None, fresh)] if fresh else []) + parts


def _from_format_3(state: dict[str, Any], path: Path) -> dict[str, Any]:
    from plantdreamer.pipeline.settings.config import from_flat_dict

    try:
        config = from_flat_dict(state["config"]).to_dict()
    except (KeyError, TypeError, AttributeError, InputError) as exc:
        raise CheckpointError(f"{path}: damaged checkpoint, bad config ({exc})") from exc
    converted = {k: v for k, v in state.items() if k != "densify"}
    converted.update(format=4, config=config, density=state.get("densify"))
    return converted
