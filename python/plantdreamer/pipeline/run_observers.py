"""The observers a run's settings ask for, built in one place: the progress pictures at
their cadence (``progress-every``, else the checkpoints) and, with ``tensorboard``, a
TensorBoard writer that also takes each progress picture."""

from __future__ import annotations

from plantdreamer.pipeline.observer import TrainerObserver
from plantdreamer.pipeline.outputs import OutputsConfig
from plantdreamer.pipeline.progress_pictures import ProgressPictures


def run_observers(outputs: OutputsConfig) -> list[TrainerObserver]:
    """The trainer's observers of a run with the outputs section ``outputs``."""
    pictures = ProgressPictures(outputs.progress_every)
    observers: list[TrainerObserver] = [pictures]
    if outputs.tensorboard:
        from plantdreamer.pipeline.tensorboard_writer import TensorBoardWriter

        writer = TensorBoardWriter()
        pictures.listeners.append(writer.picture)
        observers.append(writer)
    return observers
