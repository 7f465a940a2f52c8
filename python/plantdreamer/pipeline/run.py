"""The entry point of a generation run: claim the folder, start or resume the state, train,
export. The loop is ``trainer.py``, the outputs ``export.py``, the state ``run_state.py``."""

from __future__ import annotations

import copy
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from plantdreamer.errors import CheckpointError, InputError
from plantdreamer.exports.plant import LABEL_FILES
from plantdreamer.guidance.base import Guidance
from plantdreamer.output_folder import claim_folder
from plantdreamer.pipeline.checkpoint import (
    CHECKPOINT_NAME,
    load_checkpoint,
    restore_noise_state,
)
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.export import RunResult, export_run
from plantdreamer.pipeline.run_state import RunState
from plantdreamer.pipeline.runtime import build_guidance, check_inputs, resolve_runtime
from plantdreamer.pipeline.trainer import PlantRun, RunInterrupted, Trainer
from plantdreamer.settings import canonical

__all__ = ["RunInterrupted", "RunResult", "check_inputs", "generate"]

# What a finished run writes at its end, the file that marks it finished first (deleted
# first by --overwrite; made anew by a resumed run).
FINAL_OUTPUTS = (
    "run.json",
    "plant.ply",
    "turntable.gif",
    "turntable.mp4",
    "renders",
    "labels",
    "instances",
    "depth",
    "transforms.json",
    *LABEL_FILES,
)
# Everything a run writes.
RUN_OUTPUTS = (*FINAL_OUTPUTS, "log.csv", CHECKPOINT_NAME)
# Settings a resumed run may change: more steps continue the same run further.
RESUME_CHANGEABLE = ("steps",)


def generate(
    cfg: GenerateConfig | None,
    out_dir: str | Path,
    *,
    guidance: Guidance | None = None,
    resume: bool = False,
    changes: dict[str, Any] | None = None,
    overwrite: bool = False,
    show_progress: bool = True,
    on_step: Callable[[int], None] | None = None,
    depth_ahead: bool = True,
) -> RunResult:
    """Runs (or resumes) a generation and writes every output into ``out_dir``.

    The folder is locked for the run. A new run needs an empty folder, or ``overwrite``,
    which deletes the previous run's outputs first (never a mix of two runs).
    With ``resume=True`` the config is the checkpoint's and ``cfg`` must be None;
    ``changes`` are settings (by name) given again on resume: equal ones are fine, more
    ``steps`` continue the run further, any other difference is a CheckpointError.
    ``guidance`` overrides the one the config names (tests inject tiny models this way).
    The caller's ``cfg`` is not changed (the run works on a copy).
    Ctrl-C is honoured at the next step boundary: a checkpoint is written, then
    ``RunInterrupted`` is raised. ``depth_ahead`` computes the next step's depth
    conditioning on a worker thread (same bits; False computes it in line).
    """
    out_dir = Path(out_dir)
    if cfg is None and not resume:
        raise InputError("a config is needed unless resuming")
    if cfg is not None:
        check_inputs(cfg)
    if not resume and not overwrite and (out_dir / CHECKPOINT_NAME).is_file():
        raise InputError(
            f"{out_dir} holds a checkpoint of an earlier run; continue it with --resume "
            f"{out_dir}, pass --overwrite to start afresh, or choose another folder"
        )
    with claim_folder(
        out_dir, overwrite=overwrite and not resume, owned=RUN_OUTPUTS, allow_existing=resume
    ):
        saved = note = None
        if resume:
            saved = load_checkpoint(out_dir)
            cfg, note = resumed_config(saved, changes or {}, out_dir)
            check_inputs(cfg)
            remove_final_outputs(out_dir)
        assert cfg is not None
        cfg = copy.deepcopy(cfg)  # the caller's config is not changed
        resolve_runtime(cfg)
        resolution = cfg.train.resolution
        assert resolution is not None  # resolve_runtime decides it
        guidance = guidance if guidance is not None else build_guidance(cfg)
        if saved is None:
            state = RunState.fresh(cfg, resolution, show_progress)
        else:
            state = _restore(cfg, resolution, saved, guidance, out_dir)
        if note is not None:
            state.events.append(note)
        trainer = Trainer([PlantRun(cfg, state, out_dir)], guidance, depth_ahead=depth_ahead)
        trainer.run(show_progress, on_step)
        device = str(getattr(guidance, "device", "cpu"))
        return export_run(cfg, state, out_dir, resolution, device, show_progress)


def remove_final_outputs(out_dir: Path) -> None:
    """A resumed run's final outputs are made anew."""
    for name in FINAL_OUTPUTS:
        path = out_dir / name
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink(missing_ok=True)


def _restore(
    cfg: GenerateConfig, resolution: int, saved: dict[str, Any], guidance: Guidance, out: Path
) -> RunState:
    try:
        state = RunState.resumed(cfg, resolution, saved)
    except (KeyError, TypeError, ValueError, IndexError, RuntimeError) as exc:
        raise CheckpointError(
            f"{out / CHECKPOINT_NAME}: damaged or incompatible checkpoint "
            f"({type(exc).__name__}: {exc})"
        ) from exc
    restore_noise_state(guidance.generator, saved, out / CHECKPOINT_NAME)
    return state


def resumed_config(
    saved: dict[str, Any], changes: dict[str, Any], out_dir: Path
) -> tuple[GenerateConfig, dict[str, Any] | None]:
    """The checkpoint's config with the allowed ``changes`` (by setting name), and an event
    recording them."""
    where = out_dir / CHECKPOINT_NAME
    try:
        cfg = GenerateConfig.from_dict(saved["config"])
        cfg.validate()
        step = int(saved["step"])
    except (KeyError, TypeError, ValueError, InputError) as exc:
        raise CheckpointError(f"{where}: damaged checkpoint, bad config ({exc})") from exc
    given = {canonical(name): value for name, value in changes.items()}
    recorded = {name: cfg.get(name) for name in given}  # InputError for an unknown name
    differ = {k: v for k, v in given.items() if recorded[k] != v}
    refused = [
        f"{k}: checkpoint {recorded[k]!r}, given {v!r}"
        for k, v in differ.items()
        if k not in RESUME_CHANGEABLE
    ]
    if refused:
        raise CheckpointError(
            f"--resume continues {out_dir} with the settings it started with, and these "
            f"differ: {'; '.join(refused)}. Only --steps may change (to continue further); "
            "start a new run (another --out, or --overwrite) to change the others"
        )
    if "steps" not in differ:
        return cfg, None
    if differ["steps"] < step:
        raise CheckpointError(
            f"--steps {differ['steps']} is below the checkpoint's step {step}; "
            "a resumed run can only go further"
        )
    note = {"step": step, "event": "steps changed", "from": cfg.train.steps, "to": differ["steps"]}
    cfg.train.steps = differ["steps"]
    return cfg, note
