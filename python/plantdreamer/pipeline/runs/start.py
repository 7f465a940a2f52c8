"""A plant of a part, ready to train: started afresh from its config, or from its
checkpoint with the changes a resume allows (more ``steps``, to continue further)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

from plantdreamer.errors import CheckpointError
from plantdreamer.output_folder import check_inputs_outside, remove_owned
from plantdreamer.pipeline.runs.record import PlantEntry
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pipeline.settings.runtime import check_inputs
from plantdreamer.pipeline.state.checkpoint import CheckpointRecord, PlantCheckpoints
from plantdreamer.pipeline.state.run_outputs import FINAL_OUTPUTS, RUN_OUTPUTS
from plantdreamer.pipeline.state.run_state import RunState
from plantdreamer.pipeline.step.plant import PlantRun
from plantdreamer.settings import canonical

# Settings a resumed run may change: more steps continue the same run further.
RESUME_CHANGEABLE = ("steps",)


def start_fresh(entry: PlantEntry, show_progress: bool) -> PlantRun:
    """Step 0 of a plant whose inputs were checked (``plan.check_fresh``); what a killed
    start left in its folder goes first (its own files only). The run works on a copy of
    the entry's config."""
    remove_owned(entry.folder, RUN_OUTPUTS)
    cfg = copy.deepcopy(entry.config)
    return PlantRun(cfg, RunState.fresh(cfg, show_progress), entry.folder)


def start_resumed(
    entry: PlantEntry, file: str, changes: dict[str, Any]
) -> tuple[PlantRun, CheckpointRecord]:
    """The plant at its checkpoint ``file``, its final outputs made anew; the entry takes
    the config it continues with. CheckpointError for a damaged checkpoint."""
    files = PlantCheckpoints(entry.folder)
    saved = files.read(file)
    cfg, note = resumed_config(saved.config, saved.step, changes, entry.folder)
    check_inputs(cfg)
    if cfg.source.pointcloud is not None:
        check_inputs_outside(entry.folder, FINAL_OUTPUTS, [cfg.source.pointcloud])
    remove_owned(entry.folder, FINAL_OUTPUTS)
    entry.config = cfg
    cfg = copy.deepcopy(cfg)
    state = files.restore(cfg, saved)
    state.events.append({"step": state.step, "event": "resumed"})
    if note is not None:
        state.events.append(note)
    return PlantRun(cfg, state, entry.folder), saved


def resumed_config(
    config: GenerateConfig, step: int, changes: dict[str, Any], folder: Path
) -> tuple[GenerateConfig, dict[str, Any] | None]:
    """``config`` (a plant's, at ``step``) with the allowed ``changes`` (by setting name),
    and an event recording them."""
    cfg = copy.deepcopy(config)
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
            f"--resume continues {folder} with the settings it started with, and these "
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
