"""What a run does with each plant of its record, decided one way for every layout: done
(its finished outputs are in its folder), started afresh, resumed from a checkpoint at a
step, or failed (its inputs or its checkpoint cannot be read). Plants that resume at one
step train together (``checkpoint.common_starts``: plants trained together hold their last
common step), so no plant skips or repeats a step; plants with no checkpoint start
together afresh.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from plantdreamer.errors import PlantDreamerError
from plantdreamer.pipeline.runs.record import DONE, FAILED, RUNNING, PlantEntry, RunRecord
from plantdreamer.pipeline.settings.runtime import check_inputs
from plantdreamer.pipeline.state.checkpoint import PlantCheckpoints, common_starts
from plantdreamer.pipeline.state.run_outputs import is_finished

Fail = Callable[[PlantEntry, BaseException], None]


@dataclass
class Part:
    """Plants that train together from one step (None: a fresh start), each resumed one
    with the checkpoint file it starts from."""

    step: int | None
    plants: list[PlantEntry]
    files: dict[str, str] = field(default_factory=dict)


def check_fresh(entries: list[PlantEntry], fail: Fail) -> None:
    """Each plant's inputs, before anything is claimed or deleted: one that cannot work
    fails (``fail``: recorded, or raised)."""
    for entry in entries:
        try:
            check_inputs(entry.config)
        except (PlantDreamerError, OSError) as exc:
            fail(entry, exc)


def retry_failed(record: RunRecord) -> list[str]:
    """A resume tries every failed or interrupted plant again; the failed ones, by name."""
    retried = []
    for entry in record.plants:
        if entry.status == FAILED:
            retried.append(entry.name)
        if entry.status != DONE:
            entry.status, entry.error, entry.stopped_at = RUNNING, None, None
    return retried


def plan_run(record: RunRecord, resume: bool, fail: Fail) -> list[Part]:
    """The parts to train (fresh plants first), each plant's status set: a resume finds a
    plant done by its folder, whatever the record says."""
    live = [e for e in record.plants if e.status != FAILED]
    if not resume:
        return [Part(None, live)] if live else []
    starts: dict[str, dict[int, str]] = {}
    for entry in live:
        if is_finished(entry.folder):
            entry.status = DONE
            continue
        entry.status = RUNNING
        try:
            starts[entry.name] = PlantCheckpoints(entry.folder).starts()
        except PlantDreamerError as exc:  # a damaged checkpoint: this plant fails alone
            fail(entry, exc)
    by_name = {e.name: e for e in live}
    fresh = [by_name[n] for n, steps in starts.items() if not steps]
    check_fresh(fresh, fail)
    parts = []
    for step, names in common_starts(starts):
        members = [by_name[n] for n in names if by_name[n].status != FAILED]
        if members:
            files = {} if step is None else {n: starts[n][step] for n in names}
            parts.append(Part(step, members, files))
    return parts
