"""Resumable checkpoints of a generation run (``OUT/checkpoint.pt``), written atomically.

A checkpoint is the config, ``RunState.state_dict()`` and the guidance's noise state. Older
formats still load where their contents carry over exactly; others fail with one line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from plantdreamer.atomic import _umask  # noqa: F401  (tests check the file mode with it)
from plantdreamer.checkpoint_io import read_checkpoint, write_checkpoint
from plantdreamer.errors import CheckpointError, InputError

CHECKPOINT_NAME = "checkpoint.pt"
# 2: nested config sections, plain data only (weights_only loads);
# 3: the config records init_shape (format 2 runs began from spheres, the default is now discs,
#    so resuming one would record a shape its model was not made with);
# 4: the config in sections (source, init, train, sds, density, outputs); density control's
#    state under "density". Format 3 converts exactly (each old key has one new name).
FORMAT_VERSION = 4
_CONVERTS = (3,)


def save_checkpoint(out_dir: Path, state: dict[str, Any]) -> Path:
    path = Path(out_dir) / CHECKPOINT_NAME
    write_checkpoint(path, {"format": FORMAT_VERSION, **state})
    return path


def load_checkpoint(out_dir: Path) -> dict[str, Any]:
    path = Path(out_dir) / CHECKPOINT_NAME
    state = read_checkpoint(path)
    found = state.get("format")
    if found in _CONVERTS:
        return _from_format_3(state, path)
    if found != FORMAT_VERSION:
        what = f"format {found}" if isinstance(found, int) else "not a plantdreamer checkpoint"
        raise CheckpointError(
            f"{path}: {what}; this plantdreamer resumes formats 3 and {FORMAT_VERSION} only "
            "(start the run again with --overwrite)"
        )
    return state


# Bytes of a saved torch generator state, by device: the CPU's Mersenne Twister, CUDA's
# Philox (seed and offset).
_STATE_BYTES = {5056: "cpu", 16: "cuda"}


def noise_state(generator: Any) -> dict[str, Any]:
    """The checkpoint's entries for the guidance's noise generator (``None``: it has none)."""
    if generator is None:
        return {"guidance": None}
    return {"guidance": generator.get_state(), "guidance_device": generator.device.type}


def restore_noise_state(generator: Any, saved: dict[str, Any], where: Path) -> None:
    """Sets the guidance's noise generator to the checkpoint's state, so the resumed run draws
    the same noise. A state drawn on another kind of device (a CPU run resumed on CUDA, or a
    checkpoint from before the CUDA generator moved onto the GPU) cannot go on with the
    same noise: one line says so rather than torch's error."""
    state = saved.get("guidance")
    if state is None:
        return
    if generator is None:
        raise InputError(
            f"{where}: the checkpoint holds a guidance's noise state; this one has none"
        )
    here = generator.device.type
    # Checkpoints without the device name are told apart by the state's size.
    saved_on = saved.get("guidance_device") or _STATE_BYTES.get(int(state.numel()), "unknown")
    if saved_on != here:
        raise CheckpointError(
            f"{where}: its SDS noise was drawn on {saved_on} and this run's guidance draws on "
            f"{here}; resume with the device it was made on (--device), or start again with "
            "--overwrite"
        )
    try:
        generator.set_state(state)
    except (RuntimeError, TypeError) as exc:
        raise CheckpointError(f"{where}: damaged guidance noise state ({exc})") from exc


def _from_format_3(state: dict[str, Any], path: Path) -> dict[str, Any]:
    from plantdreamer.pipeline.config import from_flat_dict

    try:
        config = from_flat_dict(state["config"]).to_dict()
    except (KeyError, TypeError, AttributeError, InputError) as exc:
        raise CheckpointError(f"{path}: damaged checkpoint, bad config ({exc})") from exc
    converted = {k: v for k, v in state.items() if k != "densify"}
    converted.update(format=FORMAT_VERSION, config=config, density=state.get("densify"))
    return converted
