"""What a generation run writes in its folder, declared once (``output_folder.Owned``):
``--overwrite`` deletes these and nothing else, a resume remakes the final ones, a dataset
clears a plant's. Torch-free, so a dataset's dry run reads it without loading the trainer."""

from __future__ import annotations

from pathlib import Path

from plantdreamer.exports.plant import LABEL_FILES, VIEW_PNG
from plantdreamer.output_folder import tree
from plantdreamer.pipeline.progress_pictures import (
    FRAME_NAME,
    LOSS_PLOT,
    PROGRESS_DIR,
    PROGRESS_STRIP,
)
from plantdreamer.pipeline.tensorboard_writer import EVENTS_NAME, TENSORBOARD_DIR
from plantdreamer.traits.files import TRAITS_FILE

CHECKPOINT_NAME = "checkpoint.pt"
PREVIOUS_NAME = "checkpoint.prev.pt"  # kept while the plants of a group write the next one
CHECKPOINT_FILES = (CHECKPOINT_NAME, PREVIOUS_NAME)
# The guidance's noise state of each trainer that writes here (group_noise.py), kept while
# its plants train: in a plant's own folder, a group's, or a dataset unit's first plant's.
NOISE_NAME = "noise.pt"
# A finished plant's files (run.json last); with no checkpoint left, it is finished.
COMPLETE_FILES = ("plant.ply", "run.json")

# What a finished run writes at its end, the file that marks it finished first (deleted
# first by --overwrite; made anew by a resumed run).
FINAL_OUTPUTS = (
    "run.json",
    "plant.ply",
    "turntable.gif",
    "turntable.mp4",
    *tree("renders", VIEW_PNG),
    *tree("labels", VIEW_PNG, *tree("preview", VIEW_PNG)),
    *tree("instances", VIEW_PNG),
    *tree("depth", VIEW_PNG),
    "transforms.json",
    TRAITS_FILE,
    *LABEL_FILES,
)
# Everything a run writes.
# The pictures of the training's progress (pipeline.progress_pictures) and its TensorBoard
# events (pipeline.tensorboard_writer, with --tensorboard).
PROGRESS_OUTPUTS = (
    *tree(PROGRESS_DIR, FRAME_NAME),
    PROGRESS_STRIP,
    LOSS_PLOT,
    *tree(TENSORBOARD_DIR, EVENTS_NAME),
)
RUN_OUTPUTS = (*FINAL_OUTPUTS, "log.csv", *CHECKPOINT_FILES, NOISE_NAME, *PROGRESS_OUTPUTS)


def is_finished(folder: Path) -> bool:
    """A plant folder whose run finished: its complete files there, no checkpoint left."""
    return all((folder / name).is_file() for name in COMPLETE_FILES) and not any(
        (folder / name).exists() for name in CHECKPOINT_FILES
    )
