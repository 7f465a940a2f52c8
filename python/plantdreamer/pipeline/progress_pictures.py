"""Pictures of a run in progress (``ProgressPictures``, a trainer's observer), so a long run
can be looked at before it ends:

- ``progress/step_NNNNNN.png``: the Gaussians after that many steps, one small view from the
  evaluation orbit's first camera (elevation, field of view and azimuth), at the distance
  that frames the model as it is then;
- ``progress.png``: those pictures side by side, the latest on the right (at most
  ``STRIP_FRAMES``, evenly picked), each under its step;
- ``loss.png``: the log so far (``log_plot.py``: the loss and its running mean, the drawn
  timestep, the gradient norm); none for a run without guidance (it has no loss).

They are made at each checkpoint of the schedule (every ``checkpoint-every`` steps) and at
the last step, or with ``progress-every`` N every N steps and at the last, at the end of
the step that completes them. Each file is rewritten atomically and depends only on the
model and the log at that step, so a resumed run leaves the same bytes as one never stopped
(a picture past the resumed step is left out of the strip, then made again; a stop's own
checkpoint makes none). A step's pictures come before its checkpoint: a run killed between
the two resumes from the checkpoint before and makes them again, so no picture a resume
needs is ever missing. Each picture is also handed to the ``listeners`` (a TensorBoard
writer) with its plant and step.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer import atomic
from plantdreamer.pipeline.log_plot import LOSS_PLOT, write_loss_plot
from plantdreamer.pipeline.observer import TrainerObserver

__all__ = ["FRAME_NAME", "LOSS_PLOT", "PROGRESS_DIR", "PROGRESS_STRIP", "ProgressPictures"]

PROGRESS_DIR = "progress"
PROGRESS_STRIP = "progress.png"
PICTURE_PX = 128  # side of each picture: small enough to cost little at every checkpoint
STRIP_FRAMES = 12
_CAPTION_PX = 14
FRAME_NAME = re.compile(r"step_(\d{6,})\.png")


# A picture's listener: called with the plant (a ``PlantRun``), the steps done and the picture.
PictureListener = Callable[[Any, int, np.ndarray], None]


class ProgressPictures(TrainerObserver):
    """Each plant's pictures at the checkpoints of the schedule (``every`` None), or every
    ``every`` steps; each made is handed to the ``listeners``."""

    def __init__(self, every: int | None = None, listeners: Sequence[PictureListener] = ()) -> None:
        self.every, self.listeners = every, list(listeners)

    def step_end(self, step: int, plants: Sequence[Any], loss: float | None) -> None:
        if self.every is None:
            return
        for plant in plants:
            done = step + 1
            if plant.error is None and (done % self.every == 0 or done == plant.cfg.train.steps):
                self._write(plant, done)

    def checkpoint(self, step: int, plants: Sequence[Any]) -> None:
        if self.every is not None:
            return
        for plant in plants:  # the schedule's checkpoints and the last, not a stop's
            train = plant.cfg.train
            if step % train.checkpoint_every == 0 or step == train.steps:
                self._write(plant, step)

    def _write(self, plant: Any, step: int) -> None:
        frame = write_progress(plant, step)
        for listener in self.listeners:
            listener(plant, step, frame)


def write_progress(plant: Any, step: int) -> np.ndarray:
    """The pictures of a ``PlantRun`` after ``step`` steps; returns the step's picture."""
    out = Path(plant.out_dir)
    frame = _picture(plant.state.model, plant.cfg)
    (out / PROGRESS_DIR).mkdir(exist_ok=True)
    atomic.write_image(out / PROGRESS_DIR / f"step_{step:06d}.png", frame)
    atomic.write_image(out / PROGRESS_STRIP, _strip(out / PROGRESS_DIR, step))
    write_loss_plot(out / LOSS_PLOT, [row for row in plant.state.log_rows if row["step"] < step])
    return frame


def _picture(model: Any, cfg: Any) -> np.ndarray:
    import torch

    from plantdreamer.cameras import orbit
    from plantdreamer.errors import InputError
    from plantdreamer.framing import orbit_distance
    from plantdreamer.pipeline.outputs import to_uint8

    oc, px = cfg.outputs, PICTURE_PX

    def camera(distance: float) -> Any:
        return orbit(distance, oc.eval_elevation_deg, -180.0, oc.eval_fovy_deg, px, px)

    try:  # framed for this one camera (the orbit's framing looks all around: 5x the time)
        distance = orbit_distance(model.to_gaussians(), [camera(1.0)])
    except InputError:  # nothing visible is left: a blank picture says so
        return np.full((px, px, 3), to_uint8(np.float32(cfg.train.background)), np.uint8)
    with torch.no_grad():
        image, _, _ = model.render([camera(distance)], cfg.train.background)
    return to_uint8(image[0].numpy())


def _strip(folder: Path, step: int) -> Any:
    """The pictures of steps up to ``step``, side by side under their step numbers."""
    from PIL import Image, ImageDraw

    found = sorted(
        (int(m.group(1)), p)
        for p in folder.iterdir()
        if (m := FRAME_NAME.fullmatch(p.name)) and int(m.group(1)) <= step
    )
    picks = np.unique(np.linspace(0, len(found) - 1, min(STRIP_FRAMES, len(found))).round())
    chosen = [found[int(i)] for i in picks]
    strip = Image.new("RGB", (PICTURE_PX * len(chosen), PICTURE_PX + _CAPTION_PX), "white")
    draw = ImageDraw.Draw(strip)
    for k, (at, path) in enumerate(chosen):
        with Image.open(path) as picture:
            strip.paste(picture.convert("RGB"), (k * PICTURE_PX, 0))
        draw.text((k * PICTURE_PX + 4, PICTURE_PX + 1), f"step {at}", fill="black")
    return strip
