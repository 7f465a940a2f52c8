"""What watches a trainer: a ``TrainerObserver`` is called at fixed points of the loop
(nerfstudio's training callbacks), so pictures, writers and profilers see the run without
replacing its methods. Every method does nothing here; an observer overrides those it needs.

The points, in order within a step: ``phase_start`` / ``phase_end`` around each timed phase
of the step (the renders, the guidance's launch and wait, the backward passes, the
optimiser; density control's rounds, per plant), ``step_end`` once the step's updates are
done, and ``checkpoint`` when a checkpoint is due at a step, *before* its files are written
(what an observer writes there is never behind the checkpoint a resume starts from), and
``train_end`` once the trainer's loop is over, however it ended (files to close).
Observers run on the trainer's thread: what they do adds to the run's time.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


class TrainerObserver:
    def phase_start(self, phase: str) -> None:
        """A timed phase begins (``export.STEP_PHASES``, ``densify``, ``cull``, ...)."""

    def phase_end(self, phase: str, seconds: float) -> None:
        """The phase ends, after ``seconds`` of wall time."""

    def step_end(self, step: int, plants: Sequence[Any], loss: float | None) -> None:
        """Step ``step`` is done for ``plants`` (the trainer's ``PlantRun``s, those failed
        included: ``error`` says which); ``loss`` None when nothing trains."""

    def checkpoint(self, step: int, plants: Sequence[Any]) -> None:
        """A checkpoint of the live ``plants`` for a run continuing at ``step`` is about to
        be written (at the schedule's steps, the last, and a stop's)."""

    def train_end(self) -> None:
        """The trainer's loop is over: finished, stopped or failed."""


def notify(observers: Sequence[TrainerObserver], method: str, *args: Any) -> None:
    for observer in observers:
        getattr(observer, method)(*args)
