"""The one entry of every generation: ``generate_plants``, for a plant alone, a group and a
dataset unit, fresh or resumed. The command line, the Python API, the dataset's workers,
the benches and the tests all call it.

The lifecycle, the same for every layout (``layout.py``):

1. the record: new from the configs, or (a resume) found where the layout keeps it;
2. checks before anything is claimed, deleted or loaded: each fresh plant's inputs (one
   that cannot work fails by the failure policy), the models the plants share;
3. the claim: the layout's folders locked (``--overwrite``: their run outputs cleared);
4. the plan (``plan.py``): each plant done, fresh, resumed at a step, or failed; the
   settings left open decided once for the fresh plants (``runtime.resolve_plants``), and
   the record saved;
5. each part trained and exported (``sequence.py``); the record saved however it ends.

The failure policy is a parameter: ``raise`` (the first failure raises, as a plant alone
wants) or ``record`` (a failing plant is recorded and the others go on, as groups and
datasets want: each result says how its plant ended).
"""

from __future__ import annotations

import copy
import sys
from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from plantdreamer.errors import CheckpointError, InputError, RunInterrupted
from plantdreamer.guidance.base import Guidance
from plantdreamer.pipeline.export import RunResult
from plantdreamer.pipeline.observer import TrainerObserver
from plantdreamer.pipeline.runs.layout import GivenFolders, Layout, PlantAlone
from plantdreamer.pipeline.runs.plan import check_fresh, plan_run, retry_failed
from plantdreamer.pipeline.runs.record import DONE, FAILED, INTERRUPTED, RUNNING, PlantEntry
from plantdreamer.pipeline.runs.results import PlantResult, result_of
from plantdreamer.pipeline.runs.sequence import GuidanceFor, PlantFailure, RunContext, train_part
from plantdreamer.pipeline.runs.start import resumed_config
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pipeline.settings.runtime import build_guidance, check_models, resolve_plants
from plantdreamer.pipeline.step.options import StepOptions

FAILURE_POLICIES = ("raise", "record")


def generate_plants(
    cfgs: Sequence[GenerateConfig] | None,
    out: str | Path,
    *,
    layout: Layout = PlantAlone(),  # noqa: B008 (frozen: one value, never changed)
    failures: str = "raise",
    resume: bool = False,
    overwrite: bool = False,
    changes: Mapping[str, Any] | None = None,
    guidance: Guidance | None = None,
    guidance_for: GuidanceFor | None = None,
    options: StepOptions | None = None,
    observers: Sequence[TrainerObserver] = (),
    on_step: Callable[[int], None] | None = None,
    show_progress: bool = True,
) -> list[PlantResult]:
    """Trains ``cfgs`` into ``out`` as ``layout`` places them, or with ``resume`` continues
    the run there (``cfgs`` None, but for ``GivenFolders``, whose plants resume from their
    checkpoints where they have one). Returns each plant's result in the record's order.

    ``failures``: ``raise`` or ``record`` (module docstring). ``overwrite`` clears an
    earlier run's outputs (the run's own files only) before a fresh start. ``changes``:
    settings given again on a resume: equal ones are fine, more ``steps`` continue the
    run further, any other difference is a CheckpointError. ``guidance`` overrides the one
    the configs name (tests inject tiny models); else ``guidance_for`` (``build_guidance``,
    looked up when called) builds it from the plants' shared settings. ``options``: how the step runs (the same bits either way).
    ``observers`` watch the trainer (``observer.py``); ``on_step`` hears each step's end.
    The callers' configs are not changed. Ctrl-C is honoured at the next step boundary:
    the checkpoints are written, then ``RunInterrupted`` is raised."""
    out, changes = Path(out), dict(changes or {})
    if failures not in FAILURE_POLICIES:
        raise InputError(f"failures must be one of {', '.join(FAILURE_POLICIES)}, not {failures!r}")
    given = isinstance(layout, GivenFolders)
    if cfgs is None and (given or not resume):
        raise InputError("a config is needed unless resuming")
    if cfgs is not None and resume and not given:
        raise InputError("a resume continues with the settings it started with: give changes")
    if resume and overwrite:
        raise InputError("--overwrite starts afresh; it cannot go with --resume")
    if cfgs is not None:
        record = layout.new_record([copy.deepcopy(c) for c in cfgs], out)
    else:
        record = layout.found_record(out)

    def fail(entry: PlantEntry, exc: BaseException) -> None:
        if failures == "raise":
            raise exc
        entry.fail(exc, plain=isinstance(exc, PlantFailure))

    retried = set(retry_failed(record)) if resume else set()
    if not resume:
        check_fresh(record.plants, fail)
    live = [e for e in record.plants if e.status != FAILED]
    if guidance is None and live:  # the plants share their models: found before anything
        check_models(live[0].config)
    run = RunContext(
        out, layout, fail, failures == "record", changes, guidance,
        guidance_for or build_guidance, options, observers, on_step, show_progress,
    )  # fmt: skip
    trained: dict[str, RunResult] = {}
    resumed_from: dict[str, int] = {}
    trained_with: dict[str, tuple[str, ...]] = {}
    with ExitStack() as stack:
        layout.claim(stack, out, record, overwrite=overwrite, resume=resume)
        parts = plan_run(record, resume, fail)
        _check_changes_of_done(record.plants, changes)
        for part in parts:
            if part.step is None:  # the settings left open, decided once
                resolve_plants([e.config for e in part.plants])
        if show_progress and retried:
            print(f"retrying {len(retried)} plants that failed before: "
                  f"{', '.join(sorted(retried))}", file=sys.stderr)  # fmt: skip
        layout.save(record, out)
        current: list[PlantEntry] = []
        try:
            for part in parts:
                current = part.plants
                names = tuple(e.name for e in part.plants)
                for entry in part.plants:
                    trained_with[entry.name] = names
                    if part.step is not None:
                        resumed_from[entry.name] = part.step
                trained.update(train_part(part, run))
        except RunInterrupted as stop:
            for entry in record.plants:
                if entry.status == RUNNING:
                    entry.status = INTERRUPTED
                    entry.stopped_at = stop.step if entry in current else None
            stop.results = _results(record.plants, trained, resumed_from, trained_with, retried)
            raise
        finally:  # also on Ctrl-C: a plant failed before the stop stays failed on resume
            layout.save(record, out)
    return _results(record.plants, trained, resumed_from, trained_with, retried)


def _results(
    entries: list[PlantEntry],
    trained: dict[str, RunResult],
    resumed_from: dict[str, int],
    trained_with: dict[str, tuple[str, ...]],
    retried: set[str],
) -> list[PlantResult]:
    return [
        result_of(e, trained.get(e.name), resumed_from.get(e.name),
                  trained_with.get(e.name, ()), e.name in retried)
        for e in entries
    ]  # fmt: skip


def _check_changes_of_done(entries: list[PlantEntry], changes: dict[str, Any]) -> None:
    """Settings given again to a finished plant must be its own: it has no checkpoint left
    to continue from."""
    for entry in entries:
        if entry.status != DONE or not changes:
            continue
        steps = entry.config.train.steps
        cfg, _ = resumed_config(entry.config, steps, changes, entry.folder)
        if cfg.train.steps != steps:
            raise CheckpointError(
                f"{entry.folder} is finished ({steps} steps) and holds no checkpoint to train "
                "further; start a new run (another --out, or --overwrite)"
            )
