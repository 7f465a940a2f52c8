"""``TensorBoardWriter``: a trainer's observer that writes each plant's TensorBoard events in
its folder's ``tensorboard/`` (``tensorboard --logdir OUT`` shows every plant of a group or
a dataset side by side), through torch's ``SummaryWriter``. The only module that imports
TensorBoard (the ``tensorboard`` extra).

- scalars, at every step: the columns of the step's ``log.csv`` row under their own names
  (``loss``, ``grad_norm``, ``timesteps``: the plant's own draw, ``t_min``, ...), at the
  step's number in ``log.csv``; a step without a row (no guidance) logs ``gaussians``;
- images: each progress picture (``ProgressPictures`` hands it over) as ``progress``, at
  the step that completed it (``progress/step_000200.png`` at step 199).

A resumed run's events equal an unbroken run's: the writer starts at the resumed step with
TensorBoard's purge step, which hides whatever a killed run wrote from that step on, and
the events are flushed before each checkpoint's files are written (the observers'
``checkpoint``), so none that a resume does not write again is ever lost.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer.pipeline.observer import TrainerObserver
from plantdreamer.pipeline.outputs import check_tensorboard, read_samples_cell

TENSORBOARD_DIR = "tensorboard"
# The files a SummaryWriter makes there: events.out.tfevents.<time>.<host>.<pid>.<n>
EVENTS_NAME = re.compile(r"events\.out\.tfevents\.\d+\.[^/]+")
PICTURE_TAG = "progress"
_NOT_SCALARS = ("step",)


def step_scalars(row: dict[str, Any] | None) -> dict[str, float]:
    """The scalars of a ``log.csv`` row by column: its numbers, and a per-sample cell of one
    value (the plant's own draw); NaN (a figure that does not apply) and text left out."""

    scalars: dict[str, float] = {}
    for name, value in (row or {}).items():
        if name in _NOT_SCALARS:
            continue
        if isinstance(value, str):
            samples = read_samples_cell(value)
            if len(samples) != 1:
                continue
            value = samples[0]
        try:
            number = float(value)
        except (TypeError, ValueError):
            continue
        if np.isfinite(number):
            scalars[name] = number
    return scalars


class TensorBoardWriter(TrainerObserver):
    """One ``SummaryWriter`` per plant folder, opened at the first step this trainer runs."""

    def __init__(self) -> None:
        check_tensorboard()
        self.writers: dict[Path, Any] = {}

    def _writer(self, plant: Any, step: int) -> Any:
        folder = Path(plant.out_dir)
        writer = self.writers.get(folder)
        if writer is None:
            from torch.utils.tensorboard import SummaryWriter

            # A run resumed at ``step``: what a killed run wrote from there on is hidden.
            writer = SummaryWriter(str(folder / TENSORBOARD_DIR), purge_step=step or None)
            self.writers[folder] = writer
        return writer

    def step_end(self, step: int, plants: Sequence[Any], loss: float | None) -> None:
        for plant in plants:
            if plant.error is not None:
                continue
            rows = plant.state.log_rows
            row = rows[-1] if rows and rows[-1]["step"] == step else None
            scalars = step_scalars(row) if row is not None else {}
            if not scalars:
                scalars = {"gaussians": float(len(plant.state.model))}
            writer = self._writer(plant, step)
            for name, value in scalars.items():
                writer.add_scalar(name, value, step)

    def picture(self, plant: Any, done: int, frame: np.ndarray) -> None:
        """A ``ProgressPictures`` listener: the picture after ``done`` steps (a run of 0
        steps: its start, at step 0)."""
        step = max(done - 1, 0)
        self._writer(plant, step).add_image(PICTURE_TAG, frame, step, dataformats="HWC")

    def checkpoint(self, step: int, plants: Sequence[Any]) -> None:
        for writer in self.writers.values():
            writer.flush()

    def train_end(self) -> None:
        for writer in self.writers.values():
            writer.close()
        self.writers.clear()
