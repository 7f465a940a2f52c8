"""Adaptive density control as one strategy object (gsplat's ``Strategy`` shape): its
settings, its state and the two points of the loop where it acts.

- ``after_backward(step, meta, camera)``: gathers the 2D-mean gradients of the step;
- ``step_end(step, model)``: densifies and prunes (3DGS rules, ``density_ops.py``) and culls large
  Gaussians (paper Sec. 3.3, ``culling.py``) when due, and says what it did.

The loop calls only these and ``state_dict`` / ``load_state_dict``, so a density rule changes
here alone. torch loads on first use: the CLI reads the settings at start-up.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from plantdreamer.errors import InputError
from plantdreamer.settings import option_prefix, setting

if TYPE_CHECKING:
    from plantdreamer.cameras import Camera
    from plantdreamer.pipeline.model.density_ops import DensifyStats
    from plantdreamer.pipeline.model.gaussian_model import GaussianModel


@dataclass
class DensifyConfig:
    """3DGS adaptive density control in the released code's window: every ``every`` steps
    strictly between ``start`` and ``until``, clone or split Gaussians whose mean 2D-mean
    gradient (NDC units) is at least ``grad_threshold``, then prune transparent ones."""

    start: int = setting(300, "First step after which density control runs.")
    until: int = setting(900, "Step before which density control stops.")
    every: int = setting(100, "Steps between densify-and-prune rounds.")
    grad_threshold: float = setting(2e-4, "Mean 2D-mean gradient (NDC) that densifies.")
    split_scale: float = setting(
        0.04, "Larger Gaussians are split, smaller cloned (1% of the scene)."
    )
    prune_opacity: float = setting(0.05, "Gaussians less opaque than this are pruned.")
    max_gaussians: int = setting(500_000, "Most Gaussians density control makes.")
    cap_rule: str = setting(
        "strongest",
        "At the cap: densify the strongest gradients, or all then prune at random (released).",
        choices=("strongest", "random"),
    )
    split_std: float = setting(1.0, "Split samples' std as a fraction of the scale.")
    prune_screen_px: float | None = setting(
        None,
        "Also prune Gaussians whose screen radius exceeded this many pixels since the last "
        "round, before densifying (released: 1000).",
    )

    def due(self, step: int) -> bool:
        return self.start < step < self.until and step % self.every == 0


@dataclass
class CullConfig:
    """Large-Gaussian culling (paper Sec. 3.3, on log-scales): every ``every`` steps after
    ``after``, remove Gaussians with V = ||exp(s)|| > mean + ``threshold`` std."""

    threshold: float = setting(3.0, "C in V > mean + C std.")
    every: int = setting(100, "Steps between culling rounds.")
    after: int = setting(500, "Step after which culling runs.")
    volume: str = setting(
        "log",
        "V on log-scales (paper), or double-exp: exp of activated scales (released).",
        choices=("log", "double-exp"),
    )
    offset: int = setting(
        0, "Cull when step + offset is a multiple of every (released: 1, steps 599 ... 3599)."
    )

    def due(self, step: int) -> bool:
        return step > self.after and (step + self.offset) % self.every == 0

    def validate(self) -> None:
        """A negative C culls more than half the Gaussians at every round (-100: all)."""
        if self.threshold < 0:
            raise InputError(
                f"cull-threshold must be >= 0 (standard deviations), got {self.threshold}"
            )


@dataclass
class DensityConfig:
    densify: DensifyConfig = field(default_factory=DensifyConfig, metadata=option_prefix("densify"))
    cull: CullConfig = field(default_factory=CullConfig, metadata=option_prefix("cull"))

    def validate(self) -> None:
        self.cull.validate()


Timer = Callable[[str], AbstractContextManager[Any]]


class DensityControl:
    """Density control of one plant: settings, gradient statistics, hooks."""

    def __init__(self, cfg: DensityConfig, seed: int, n_gaussians: int) -> None:
        from plantdreamer.pipeline.model.density_ops import DensifyStats

        self.cfg, self.seed = cfg, seed
        self.stats: DensifyStats = DensifyStats.zeros(n_gaussians)

    def after_backward(self, step: int, meta: dict[str, Any], camera: Camera) -> None:
        """Adds the step's 2D-mean gradients (before the optimiser moves the Gaussians)."""
        grad = meta["means2d"].grad
        if step < self.cfg.densify.until and grad is not None:
            self.stats.update(grad, meta["radii"], camera.width, camera.height)

    def step_end(
        self, step: int, model: GaussianModel, timer: Timer | None = None
    ) -> list[dict[str, Any]]:
        """Densifies and culls when due; returns the events (what each round did)."""
        import torch

        from plantdreamer.pipeline.model.culling import large_gaussian_mask
        from plantdreamer.pipeline.model.density_ops import DensifyStats, densify_and_prune, remove

        timed = timer or (lambda name: nullcontext())
        dens, cull, events = self.cfg.densify, self.cfg.cull, []
        if dens.due(step):
            with timed("densify"):
                gen = torch.Generator().manual_seed(self.seed * 1_000_003 + step)
                before = _class_counts(model)
                counts = densify_and_prune(
                    model,
                    self.stats,
                    dens.grad_threshold,
                    dens.split_scale,
                    dens.prune_opacity,
                    dens.max_gaussians,
                    gen,
                    dens.cap_rule,
                    dens.split_std,
                    dens.prune_screen_px,
                )
                self.stats = DensifyStats.zeros(len(model))
            event = {"step": step, "event": "densify", **counts, "gaussians": len(model)}
            if model.labels is not None:
                event["classes_before"], event["classes_after"] = before, _class_counts(model)
            events.append(event)
        if cull.due(step):
            with timed("cull"):
                mask, stats = large_gaussian_mask(
                    model.params["log_scales"], cull.threshold, cull.volume
                )
                if stats["culled"]:
                    self.stats = remove(model, self.stats, mask)
            events.append({"step": step, "event": "cull", **stats, "gaussians": len(model)})
        return events

    def state_dict(self) -> dict[str, Any]:
        stats = self.stats
        return {"grad_sum": stats.grad_sum, "count": stats.count, "max_radius": stats.max_radius}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        from plantdreamer.pipeline.model.density_ops import DensifyStats

        # Checkpoints before the screen-size prune hold no max_radius: zeros.
        self.stats = DensifyStats(state["grad_sum"], state["count"], state.get("max_radius"))


def _class_counts(model: GaussianModel) -> dict[str, int]:
    from plantdreamer.labels import class_counts

    labels = model.labels
    return {} if labels is None else class_counts(labels[:, 0].numpy())
