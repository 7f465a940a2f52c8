"""Several plants trained together in one trainer: ``OUT/<species>-s<seed>/`` per plant.

The plants share every setting but their seed and point cloud (one guidance serves them
all: one batched network call per step, or one per half with ``overlap``), and keep their
own cameras, optimiser, density control, labels, checkpoint and outputs. Each plant starts,
trains and exports through the same sequence as a plant alone (``run.py``); this module
keeps the group's record, ``OUT/group.json`` (``group_record.py``): a plant that fails is
recorded there and the others go on. The same group (same plants, same order) gives the same
bytes run after run and after Ctrl-C + resume. The guidance's noise and timesteps come from
one generator (seeded by the first plant), so a plant made in a group is not the plant made
alone with SDS (docs/scaling.md).

A resume reconciles the record with the plant folders: a plant whose folder holds its
finished outputs is done, one whose record is stale (``running``) resumes from its
checkpoint or, with none, starts again, and one that failed is tried again (as a dataset
rerun does: "run the same command again" finishes what failed; it says how many).
Plants resume together from their last common checkpoint (``checkpoint.common_starts``), so
no plant skips or repeats a step.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.guidance.base import Guidance
from plantdreamer.output_folder import Owned, claim_folder, tree
from plantdreamer.pipeline import outputs
from plantdreamer.pipeline.checkpoint import CHECKPOINT_FILES, PlantCheckpoints, common_starts
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.export import RunResult
from plantdreamer.pipeline.group_record import (
    GROUP_FILE,
    MAX_GROUP_PLANTS,
    PER_PLANT,
    failed,
    failed_plants,
    mark_failed,
    new_record,
    plant_dir,
    plant_name,
    read_record,
)
from plantdreamer.pipeline.run import (
    RUN_OUTPUTS,
    GuidanceFor,
    PlantFailure,
    RunInterrupted,
    Started,
    start_plant,
    train_plants,
)
from plantdreamer.pipeline.runtime import build_guidance, check_inputs, check_models
from plantdreamer.pipeline.step.options import StepOptions
from plantdreamer.pipeline.trainer import PlantRun

__all__ = [
    "GROUP_FILE",
    "PER_PLANT",
    "GroupResult",
    "failed_plants",
    "generate_group",
    "parse_seeds",
    "plant_name",
]


@dataclass
class GroupResult:
    out_dir: Path
    done: dict[str, RunResult] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)  # plant -> one-line error
    resumed_from: dict[str, int] = field(default_factory=dict)  # plant -> its checkpoint's step
    trained_with: dict[str, list[str]] = field(default_factory=dict)  # plant -> its part
    retried: list[str] = field(default_factory=list)  # failed plants a resume tries again


def parse_seeds(text: str) -> list[int]:
    """``--seeds`` (``plantdreamer.seeds``' grammar), no more than a group holds."""
    from plantdreamer.seeds import TooManySeeds
    from plantdreamer.seeds import parse_seeds as parse

    try:
        return parse(text, MAX_GROUP_PLANTS)
    except TooManySeeds as many:
        raise InputError(
            f"--seeds {text} makes a group of {many.count} plants; one trainer holds at most "
            f"{MAX_GROUP_PLANTS} (as --plants-per-gpu): train them as several groups, or with "
            "`plantdreamer dataset --seeds`"
        ) from None


def generate_group(
    cfgs: list[GenerateConfig] | None,
    out_dir: str | Path,
    *,
    guidance: Guidance | None = None,
    guidance_for: GuidanceFor | None = None,
    resume: bool = False,
    overwrite: bool = False,
    show_progress: bool = True,
    on_step: Callable[[int], None] | None = None,
    options: StepOptions | None = None,
    plant_dirs: list[Path] | None = None,
) -> GroupResult:
    """Trains ``cfgs`` together into ``out_dir`` (or, with ``resume``, continues the group
    there). ``guidance`` overrides the one the configs name (tests inject tiny models);
    else ``guidance_for`` (``build_guidance``, looked up when called) builds it from the first
    plant's resolved config. ``plant_dirs``
    puts the plants in these folders (named by them) rather than in ``out_dir``, which then
    holds only ``group.json`` (a dataset's plant folders); the record is then made from
    ``cfgs`` with or without ``resume``, and a plant with a checkpoint resumes from it."""
    out = Path(out_dir)
    if resume and plant_dirs is None:
        record = read_record(out)
    else:
        record = new_record(cfgs or [], plant_dirs)
    if guidance is None:  # the plants share their models: found before anything
        check_models(cfgs[0] if cfgs else GenerateConfig.from_dict(record["plants"][0]["config"]))
    owned: list[Owned] = [GROUP_FILE]
    if plant_dirs is None and not resume:  # a plant whose inputs fail, fails alone, untouched
        for entry, cfg in zip(record["plants"], cfgs or [], strict=True):
            try:
                check_inputs(cfg)
            except (PlantDreamerError, OSError) as exc:
                mark_failed(entry, exc)
                continue
            owned += tree(entry["name"], *RUN_OUTPUTS)
    inputs = [c.source.pointcloud for c in cfgs or [] if c.source.pointcloud is not None]
    with claim_folder(out, overwrite=overwrite and not resume, owned=owned,
                      allow_existing=resume, inputs=inputs):  # fmt: skip
        result = GroupResult(out)
        part: list[dict[str, Any]] = []
        try:
            with ExitStack() as stack:
                parts = _reconcile(record, out, resume, plant_dirs is None, result, stack)
                if result.retried and show_progress:
                    print(
                        f"retrying {len(result.retried)} plants that failed before: "
                        f"{', '.join(result.retried)}",
                        file=sys.stderr,
                    )
                outputs.write_json(out / GROUP_FILE, record)
                by_dir = {plant_dir(out, e): e for e in record["plants"]}

                def failure(p: PlantRun, exc: BaseException) -> None:
                    _fail(by_dir[p.out_dir], result, exc)

                def done(p: PlantRun, run: RunResult) -> None:
                    by_dir[p.out_dir]["status"] = "done"
                    result.done[by_dir[p.out_dir]["name"]] = run

                for start, part, files in parts:
                    started = _start(start, part, files, out, stack, result, show_progress)
                    if not started:
                        continue
                    train_plants(
                        started, out, guidance=guidance,
                        guidance_for=guidance_for or build_guidance,
                        show_progress=show_progress, on_step=on_step, options=options,
                        on_failure=failure, on_done=done,
                    )  # fmt: skip
        except RunInterrupted as stop:
            for entry in record["plants"]:
                if entry["status"] == "running":
                    at = f" at step {stop.step}" if any(e is entry for e in part) else ""
                    entry["status"] = f"interrupted{at}"
            raise
        finally:  # also on Ctrl-C: a plant failed before the stop stays failed on resume
            outputs.write_json(out / GROUP_FILE, record)
        for entry in record["plants"]:
            if entry["status"] == "done" and entry["name"] not in result.done:
                result.done[entry["name"]] = _finished(plant_dir(out, entry))
        return result


Part = tuple[int | None, list[dict[str, Any]], dict[str, str]]


def _reconcile(
    record: dict[str, Any],
    out: Path,
    resume: bool,
    by_folders: bool,
    result: GroupResult,
    stack: ExitStack,
) -> list[Part]:
    """The plants to train, in parts that each start at one step: (step or None for a fresh
    start, the plants' entries, each plant's checkpoint file by name). A plant that cannot
    be read fails alone; a finished one is claimed too (its folder is locked for the run,
    and a killed run's lock file goes)."""
    todo = []
    for entry in record["plants"]:
        folder = plant_dir(out, entry)
        status = entry["status"]
        entry.pop("retry", None)  # the mark of records written before every failure retried
        if resume and status.startswith("failed"):
            result.retried.append(entry["name"])
            entry["status"] = status = "running"
        if status.startswith("failed"):
            continue
        if by_folders and resume:  # done if its outputs say so, whatever the record says
            status = "done" if _is_finished(folder) else "running"
            if status == "done":
                stack.enter_context(claim_folder(folder, allow_existing=True))
        if status == "done":
            entry["status"] = "done"
            continue
        entry["status"] = "running"
        todo.append(entry)
    result.failed.update(failed(record))
    if not resume:
        return [(None, todo, {})] if todo else []
    starts: dict[str, dict[int, str]] = {}
    for entry in todo:
        try:
            starts[entry["name"]] = PlantCheckpoints(plant_dir(out, entry)).starts()
        except PlantDreamerError as exc:  # a damaged checkpoint: this plant fails alone
            _fail(entry, result, exc)
    by_name = {e["name"]: e for e in todo}
    return [
        (step, [by_name[n] for n in members],
         {n: starts[n][step] for n in members} if step is not None else {})
        for step, members in common_starts(starts)
    ]  # fmt: skip


def _is_finished(folder: Path) -> bool:
    """Its last output written (run.json) and no checkpoint left to resume."""
    return (folder / "run.json").is_file() and not any(
        (folder / name).exists() for name in CHECKPOINT_FILES
    )


def _start(
    step: int | None,
    part: list[dict[str, Any]],
    files: dict[str, str],
    out: Path,
    stack: ExitStack,
    result: GroupResult,
    show_progress: bool,
) -> list[Started]:
    """Each plant of a part, fresh or from its checkpoint; a plant that cannot start (bad
    input, damaged checkpoint) is failed alone."""
    started = []
    names = [e["name"] for e in part]
    for entry in part:
        name = entry["name"]
        result.trained_with[name] = names
        try:
            cfg = None if step is not None else GenerateConfig.from_dict(entry["config"])
            start = None if step is None else (step, files[name])
            started.append(start_plant(stack, cfg, plant_dir(out, entry), start=start,
                                       changes={}, overwrite=True, show_progress=show_progress))  # fmt: skip
            if step is not None:
                result.resumed_from[name] = step
        except Exception as exc:  # this plant's own failure: the others go on
            _fail(entry, result, exc)
    return started


def _finished(folder: Path) -> RunResult:
    run = json.loads((folder / "run.json").read_text())
    return RunResult(
        folder, folder / "plant.ply", GenerateConfig.from_dict(run["config"]).train.steps,
        run["gaussians"]["final"], run["timings_s"],
    )  # fmt: skip


def _fail(entry: dict[str, Any], result: GroupResult, exc: BaseException) -> None:
    result.failed[entry["name"]] = mark_failed(entry, exc, plain=isinstance(exc, PlantFailure))
