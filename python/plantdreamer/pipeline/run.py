"""The entry sequence of every generation run, one plant or a group: claim each plant's
folder, start or resume its state, train the plants together, export each. ``generate`` is
a run of one plant; ``group.py`` keeps a group's record around the same sequence. The loop
is ``trainer.py``, the outputs ``export.py``, the state ``run_state.py``, the checkpoints
``checkpoint.py``."""

from __future__ import annotations

import copy
import sys
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from plantdreamer.errors import CheckpointError, InputError
from plantdreamer.guidance.base import Guidance
from plantdreamer.output_folder import claim_folder, remove_owned
from plantdreamer.output_locks import check_not_inside_held
from plantdreamer.pipeline.checkpoint import (
    CHECKPOINT_NAME,
    CheckpointRecord,
    PlantCheckpoints,
    restore_noise_state,
)
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.export import RunResult, export_run
from plantdreamer.pipeline.run_outputs import FINAL_OUTPUTS, RUN_OUTPUTS
from plantdreamer.pipeline.run_state import RunState
from plantdreamer.pipeline.runtime import (
    build_guidance,
    check_inputs,
    check_models,
    record_overlap,
    resolve_runtime,
)
from plantdreamer.pipeline.step.options import StepOptions
from plantdreamer.pipeline.trainer import PlantRun, RunInterrupted, Trainer
from plantdreamer.settings import canonical
from plantdreamer.thread_policy import pinned_torch_threads

__all__ = ["RunInterrupted", "RunResult", "check_inputs", "generate"]

# Settings a resumed run may change: more steps continue the same run further.
RESUME_CHANGEABLE = ("steps",)

GuidanceFor = Callable[[GenerateConfig], Guidance]


@dataclass
class Started:
    """A plant ready to train, and the checkpoint it resumed from (None: a fresh start)."""

    plant: PlantRun
    saved: CheckpointRecord | None


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
    options: StepOptions | None = None,
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
    ``RunInterrupted`` is raised. ``options``: how the step runs (``StepOptions``, the same
    bits either way).
    """
    out_dir = Path(out_dir)
    if cfg is None and not resume:
        raise InputError("a config is needed unless resuming")
    if cfg is not None:  # everything checked before anything is deleted or loaded
        check_inputs(cfg)
        if guidance is None:
            check_models(cfg)
    check_not_inside_held(out_dir, f"output folder {out_dir}")  # in use: said first
    if not resume and not overwrite and (out_dir / CHECKPOINT_NAME).is_file():
        raise InputError(
            f"{out_dir} holds a checkpoint of an earlier run; continue it with --resume "
            f"{out_dir}, pass --overwrite to start afresh, or choose another folder"
        )
    with ExitStack() as stack:
        start = None
        if resume:  # the folder's latest checkpoint (CheckpointError if it has none)
            found = PlantCheckpoints(out_dir).starts() if out_dir.is_dir() else {}
            start = (max(found), found[max(found)]) if found else (0, CHECKPOINT_NAME)
        started = start_plant(
            stack, cfg, out_dir, start=start, changes=changes or {}, overwrite=overwrite,
            show_progress=show_progress, models=guidance is None,
        )  # fmt: skip
        results = train_plants(
            [started], out_dir, guidance=guidance, show_progress=show_progress,
            on_step=on_step, options=options,
        )  # fmt: skip
        return results[out_dir]


def start_plant(
    stack: ExitStack,
    cfg: GenerateConfig | None,
    out_dir: Path,
    *,
    start: tuple[int, str] | None,
    changes: dict[str, Any],
    overwrite: bool,
    show_progress: bool,
    models: bool = False,
) -> Started:
    """Claims ``out_dir`` (for the life of ``stack``) and starts its plant: afresh from
    ``cfg`` (``start`` None), or from the checkpoint at ``start`` = (step, file name) with
    ``cfg`` None. The plant's own failures raise (CheckpointError for a damaged checkpoint).
    ``models``: a resumed config's models are checked too before its final outputs go."""
    resume = start is not None
    if cfg is not None:  # a fresh start: its inputs checked before its folder is claimed
        check_inputs(cfg)
    inputs = [cfg.source.pointcloud] if cfg is not None and cfg.source.pointcloud else []
    stack.enter_context(
        claim_folder(out_dir, overwrite=overwrite and not resume, owned=RUN_OUTPUTS,
                     allow_existing=resume, inputs=inputs)
    )  # fmt: skip
    files = PlantCheckpoints(out_dir)
    saved = note = None
    if start is not None:
        saved = files.read(start[1])
        cfg, note = resumed_config(saved, changes, out_dir)
        check_inputs(cfg)
        if models:
            check_models(cfg)
        if cfg.source.pointcloud is not None:
            from plantdreamer.output_folder import check_inputs_outside

            check_inputs_outside(out_dir, FINAL_OUTPUTS, [cfg.source.pointcloud])
        remove_final_outputs(out_dir)
    assert cfg is not None
    cfg = copy.deepcopy(cfg)  # the caller's config is not changed
    resolve_runtime(cfg)
    if saved is None:
        state = RunState.fresh(cfg, show_progress)
    else:
        state = files.restore(cfg, saved)
        state.events.append({"step": state.step, "event": "resumed"})
    if note is not None:
        state.events.append(note)
    return Started(PlantRun(cfg, state, out_dir), saved)


def train_plants(
    started: list[Started],
    out_dir: Path,
    *,
    guidance: Guidance | None = None,
    guidance_for: GuidanceFor = build_guidance,
    show_progress: bool = True,
    on_step: Callable[[int], None] | None = None,
    options: StepOptions | None = None,
    on_failure: Callable[[PlantRun, BaseException], None] | None = None,
    on_done: Callable[[PlantRun, RunResult], None] | None = None,
) -> dict[Path, RunResult]:
    """Trains the started plants together (all at the same step) and exports each; the
    results by plant folder. ``guidance`` (else ``guidance_for`` the first plant's config)
    guides them; a checkpoint's noise state is restored into it. ``on_failure``: a plant
    that fails (in training or its export) is reported there and the others go on (a
    group); without it the failure raises (one plant). ``on_done`` hears of each plant as
    its export ends (a stop between two exports keeps the first). ``out_dir`` is the folder
    ``RunInterrupted`` names. torch runs on the plants' ``torch-threads`` throughout (the
    guidance's loading and prompts, training, export), whatever the machine's cores."""
    plants = [s.plant for s in started]
    with pinned_torch_threads(plants[0].cfg.train.torch_threads):
        guidance = guidance if guidance is not None else guidance_for(plants[0].cfg)
        saved = started[0].saved
        if saved is not None:
            restore_noise_state(guidance.generator, saved, plants[0].out_dir / CHECKPOINT_NAME)
            if show_progress:
                print(f"resuming at step {plants[0].state.step}", file=sys.stderr)
        device = str(getattr(guidance, "device", "cpu"))
        record_overlap([p.cfg for p in plants], torch.device(device))
        trainer = Trainer(plants, guidance, options=options,
                          isolate_failures=on_failure is not None, out_dir=out_dir)  # fmt: skip
        results: dict[Path, RunResult] = {}
        with trainer.stops_handled():
            try:
                trainer.run(show_progress, on_step)
            finally:  # the plants that failed in training, reported however the run ends
                for p in plants:
                    if p.error is not None and on_failure is not None:
                        on_failure(p, PlantFailure(p.error))
            for p in plants:
                if p.error is not None:
                    continue
                trainer.stop_point()
                try:
                    results[p.out_dir] = export_run(
                        p.cfg, p.state, p.out_dir, device, show_progress, trainer.stop_point
                    )
                except Exception as exc:
                    if on_failure is None:
                        raise
                    on_failure(p, exc)
                    continue
                if on_done is not None:
                    on_done(p, results[p.out_dir])
    return results


class PlantFailure(Exception):
    """A plant's failure recorded by the trainer (its message is the error)."""


def remove_final_outputs(out_dir: Path) -> None:
    """A resumed run's final outputs are made anew (its own files only)."""
    remove_owned(out_dir, FINAL_OUTPUTS)


def resumed_config(
    saved: CheckpointRecord, changes: dict[str, Any], out_dir: Path
) -> tuple[GenerateConfig, dict[str, Any] | None]:
    """The checkpoint's config with the allowed ``changes`` (by setting name), and an event
    recording them."""
    cfg, step = copy.deepcopy(saved.config), saved.step
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
