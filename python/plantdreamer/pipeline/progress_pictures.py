"""Pictures of a run in progress, written at each checkpoint (``ProgressPictures``, a
trainer's observer) so a long run can be looked at before it ends:

- ``progress/step_NNNNNN.png``: the Gaussians at that checkpoint, one small view from the
  evaluation orbit's first camera (elevation, field of view and azimuth), at the distance
  that frames the model as it is then;
- ``progress.png``: those pictures side by side, the latest on the right (at most
  ``STRIP_FRAMES``, evenly picked), each under its step;
- ``loss.png``: the loss of every trained step so far (``log.csv``) and its running mean,
  drawn by matplotlib; none for a run without guidance (it has no loss).

Each file is rewritten atomically and depends only on the model and the log at that step, so
a resumed run leaves the same bytes as one never stopped (a picture past the resumed step is
left out of the strip, then made again; a stop's own checkpoint makes none). They are written
before the checkpoint of their step: a run killed between the two resumes from the
checkpoint before and makes them again, so no picture a resume needs is ever missing.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer import atomic
from plantdreamer.pipeline.observer import TrainerObserver

PROGRESS_DIR = "progress"
PROGRESS_STRIP = "progress.png"
LOSS_PLOT = "loss.png"
PICTURE_PX = 128  # side of each picture: small enough to cost little at every checkpoint
STRIP_FRAMES = 12
_CAPTION_PX = 14
FRAME_NAME = re.compile(r"step_(\d{6,})\.png")


class ProgressPictures(TrainerObserver):
    """Each plant's pictures at the checkpoints of the schedule."""

    def checkpoint(self, step: int, plants: Any) -> None:
        for plant in plants:
            write_progress(plant, step)


def write_progress(plant: Any, step: int) -> None:
    """The pictures of a ``PlantRun`` whose checkpoint at ``step`` is due: at the checkpoints
    of the schedule (every ``checkpoint-every`` steps, and the last), not at a stop's, so a
    stopped and resumed run shows the same pictures."""
    train = plant.cfg.train
    if step % train.checkpoint_every and step != train.steps:
        return
    out = Path(plant.out_dir)
    frame = _picture(plant.state.model, plant.cfg)
    (out / PROGRESS_DIR).mkdir(exist_ok=True)
    atomic.write_image(out / PROGRESS_DIR / f"step_{step:06d}.png", frame)
    atomic.write_image(out / PROGRESS_STRIP, _strip(out / PROGRESS_DIR, step))
    losses = [(row["step"], row["loss"]) for row in plant.state.log_rows if row.get("step") < step]
    if any(loss is not None for _, loss in losses):
        write_loss_plot(out / LOSS_PLOT, losses)


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


def write_loss_plot(path: Path, losses: list[tuple[int, float | None]]) -> None:
    """``loss.png``: the loss of each step and its running mean (over a 50th of the steps)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    steps = np.array([s for s, v in losses if v is not None], np.float64)
    values = np.array([v for _, v in losses if v is not None], np.float64)
    window = max(1, len(values) // 50)
    mean = np.convolve(values, np.ones(window) / window, mode="valid")
    figure = Figure(figsize=(5, 3), dpi=100)
    axes = figure.add_subplot()
    axes.plot(steps, values, lw=0.6, alpha=0.4, color="tab:green", label="loss")
    if window > 1:
        axes.plot(steps[window - 1 :], mean, lw=1.5, color="tab:green",
                  label=f"mean of {window} steps")  # fmt: skip
    if len(values) and np.all(values > 0) and values.max() / values.min() > 100:
        axes.set_yscale("log")
    axes.set_xlabel("step")
    axes.set_ylabel("loss")
    axes.set_xlim(0, max(1.0, math.ceil(steps.max() + 1) if len(steps) else 1.0))
    if window > 1:
        axes.legend(loc="upper right", frameon=False)
    figure.subplots_adjust(left=0.16, bottom=0.16, right=0.97, top=0.95)  # tight_layout: 2x
    # No "Software" entry: the same losses give the same bytes whatever matplotlib wrote it.
    atomic.atomic_write(
        path, lambda tmp: figure.savefig(tmp, format="png", metadata={"Software": None})
    )
