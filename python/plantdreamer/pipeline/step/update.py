"""A plant's host work after the rasterizer's backward: the gradient checks, density
statistics, Adam and the log row. One task per plant on the trainer's host pool."""

from __future__ import annotations

import math
from typing import Any

import torch

from plantdreamer.cameras import Camera
from plantdreamer.errors import PlantDreamerError
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.outputs import samples_cell
from plantdreamer.pipeline.step.plant import PlantRun


def update_plant(
    plant: PlantRun,
    step: int,
    loss: float,
    culprit: bool,
    render_info: dict[str, Any],
    camera: Camera,
    stats: dict[str, float | list[float]],
    k: int,
    batch: int,
) -> PlantDreamerError | None:
    """Checks the ``k``-th plant of a ``batch`` and applies its step; returns its failure
    (a non-finite gradient, or ``culprit``: its render's gradient made the loss
    non-finite) instead of raising it, so the other plants' updates go on."""
    model = plant.state.model
    try:
        check_finite_gradients(model, step)
        if culprit:
            raise PlantDreamerError(
                f"loss became {loss} at step {step}; stopping (no output written)"
            )
    except PlantDreamerError as exc:
        return exc
    plant.state.density.after_backward(step, render_info, camera)
    assert model.optimizer is not None  # the models are built with learning rates
    model.optimizer.step()
    row = {"step": step, "loss": loss, "gaussians": len(model)}
    plant.state.log_rows.append(row | plant_stats(stats, k, batch))
    return None


def plant_stats(stats: dict[str, float | list[float]], k: int, batch: int) -> dict[str, Any]:
    """The guidance's figures as the ``k``-th plant of a ``batch`` logs them: the batch's
    numbers as they are, and of each per-sample figure its own sample's only (one camera
    per plant and step), written as a log.csv cell."""
    own: dict[str, Any] = {}
    for key, value in stats.items():
        if isinstance(value, list):
            assert len(value) == batch, (key, len(value), batch)
            own[key] = samples_cell(value[k : k + 1])
        else:
            own[key] = value
    return own


def check_finite_gradients(model: GaussianModel, step: int) -> None:
    """Stops before a NaN or Inf gradient reaches the Gaussians through Adam (whose moments
    it would poison for every later step)."""
    for name, p in model.params.items():
        # A finite sum proves every value finite (one reduction, no mask); only a non-finite
        # one (a bad value, or rarely an overflowing sum) runs the exact test.
        if p.grad is None or math.isfinite(float(p.grad.sum())):
            continue
        if not bool(torch.isfinite(p.grad).all()):
            bad = int((~torch.isfinite(p.grad)).sum())
            raise PlantDreamerError(
                f"non-finite gradient on the Gaussians' {name} ({bad} values) at step {step}; "
                "stopping (no output written)"
            )
