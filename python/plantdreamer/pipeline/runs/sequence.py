"""One part of a run, from its start to its plants' outputs: start each plant (afresh, or
from its checkpoint), build the group's guidance (its noise restored on a resume), train
the plants together, export each. A plant's own failure goes to the run's failure policy
(``fail``: recorded and the others go on, or raised); a stop (Ctrl-C, SIGTERM) writes the
checkpoints and raises ``RunInterrupted``, between steps or between two plants' exports.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from plantdreamer.errors import CheckpointError
from plantdreamer.guidance.base import Guidance
from plantdreamer.pipeline.export import RunResult, export_run
from plantdreamer.pipeline.observer import TrainerObserver
from plantdreamer.pipeline.run_observers import run_observers
from plantdreamer.pipeline.runs.layout import Layout
from plantdreamer.pipeline.runs.plan import Fail, Part
from plantdreamer.pipeline.runs.record import DONE, PlantEntry
from plantdreamer.pipeline.runs.start import start_fresh, start_resumed
from plantdreamer.pipeline.settings.group_settings import GroupSettings
from plantdreamer.pipeline.state.checkpoint import CheckpointRecord
from plantdreamer.pipeline.state.group_noise import GroupNoise, restore_noise_state
from plantdreamer.pipeline.step.options import StepOptions
from plantdreamer.pipeline.step.plant import PlantRun
from plantdreamer.pipeline.trainer import Trainer
from plantdreamer.thread_policy import pinned_torch_threads

GuidanceFor = Callable[[GroupSettings], Guidance]


@dataclass
class RunContext:
    """What every part of a run shares."""

    out: Path
    layout: Layout
    fail: Fail
    isolate: bool  # a plant's failure is recorded and the others go on
    changes: dict[str, Any]
    guidance: Guidance | None
    guidance_for: GuidanceFor
    options: StepOptions | None
    observers: Sequence[TrainerObserver]
    on_step: Callable[[int], None] | None
    show_progress: bool


class PlantFailure(Exception):
    """A plant's failure recorded by the trainer (its message is the error)."""


def train_part(part: Part, run: RunContext) -> dict[str, RunResult]:
    """Trains and exports ``part``'s plants; the finished ones' results by name."""
    started: list[tuple[PlantEntry, PlantRun]] = []
    saved: list[CheckpointRecord] = []
    for entry in part.plants:
        try:
            if part.step is None:
                started.append((entry, start_fresh(entry, run.show_progress)))
            else:
                plant, record = start_resumed(entry, part.files[entry.name], run.changes)
                started.append((entry, plant))
                saved.append(record)
        except Exception as exc:  # this plant's own failure: the others go on
            run.fail(entry, exc)
    if not started:
        return {}
    plants = [p for _, p in started]
    entries = {id(p): e for e, p in started}
    settings = GroupSettings.of([p.cfg for p in plants])
    noise = GroupNoise(run.layout.noise_folder(run.out, part.plants), [e.name for e, _ in started])
    results: dict[str, RunResult] = {}
    with pinned_torch_threads(settings.train.torch_threads):
        guidance = run.guidance if run.guidance is not None else run.guidance_for(settings)
        start = plants[0].state.step
        if part.step is not None:
            _restore_noise(guidance, part, start, saved, run)
            if run.show_progress:
                print(f"resuming at step {start}", file=sys.stderr)
        trainer = Trainer(
            plants, guidance, settings, start=start, noise=noise, resume_folder=run.out,
            options=run.options, isolate_failures=run.isolate,
            observers=[*run_observers(settings.outputs), *run.observers],
        )  # fmt: skip
        with trainer.stops_handled():
            try:
                trainer.run(run.show_progress, run.on_step)
            finally:  # the plants that failed in training, recorded however the run ends
                for p in plants:
                    if p.error is not None and run.isolate:
                        run.fail(entries[id(p)], PlantFailure(p.error))
            noise.remove()  # trained to the end: a resume only exports
            for p in plants:
                if p.error is not None:
                    continue
                trainer.stop_point()
                entry = entries[id(p)]
                device = str(getattr(guidance, "device", "cpu"))
                try:
                    results[entry.name] = export_run(
                        p.cfg, p.state, p.out_dir, device, run.show_progress, trainer.stop_point
                    )
                except Exception as exc:
                    run.fail(entry, exc)
                    continue
                entry.status = DONE
    return results


def _restore_noise(
    guidance: Guidance, part: Part, step: int, saved: list[CheckpointRecord], run: RunContext
) -> None:
    """The guidance's noise at the part's step: the group's (``GroupNoise``), or the copy a
    format-4 checkpoint carried. A part resumed at its last step only exports (none needed)."""
    names = [e.name for e in part.plants]
    for folder in run.layout.noise_folders(run.out, part.plants):
        found = GroupNoise(folder, names).read(step)
        if found is not None:
            restore_noise_state(guidance.generator, found, folder / "noise.pt")
            return
    older = next((r.noise for r in saved if r.noise is not None), None)
    if older is not None:
        restore_noise_state(guidance.generator, older, part.plants[0].folder)
        return
    steps = part.plants[0].config.train.steps
    if guidance.generator is not None and step < steps:
        raise CheckpointError(
            f"{run.out}: no noise state of the guidance at step {step} (noise.pt missing or "
            "damaged); start the run again with --overwrite"
        )
