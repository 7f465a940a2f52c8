"""The guidance protocol the optimiser calls, and the two simple implementations.

A guidance turns rendered images into a scalar loss whose gradient flows back into the
renders (and through the rasterizer into the Gaussians). The optimiser calls

    out = guidance(images, depth_cond, cameras, step)
    out.loss.backward()

with ``images`` [B, H, W, 3] float32 in [0, 1] (requiring grad), ``depth_cond`` the cleaned
[B, 1, h, w] depth conditioning in [0, 1] (or None when ``needs_depth`` is False), the
``Camera`` of each image, and the optimisation step (schedules depend on it).

A guidance that runs on a GPU may also offer ``launch`` (same arguments), which queues the
same work and returns a ``PendingOutput`` without waiting for the device: its figures stay
on the device until ``result()`` (or the trainer's one read-back) copies them over. The
trainer launches one half of a group while the host renders the other (``guidance/in_flight.py``).

Besides the call, the loop reads three attributes: ``needs_depth`` (whether to render depth
conditioning), ``resolution`` (the square size of that conditioning; None when no depth is
needed) and ``generator`` (the guidance's own random generator, whose state checkpoints
hold so a resumed run draws the same noise; None when it draws no random numbers).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import torch

from plantdreamer.cameras import Camera
from plantdreamer.errors import InputError

# The stat holding every sample's drawn diffusion timestep (a per-sample figure): the
# column of log.csv that the known-answer check reads the draws from.
TIMESTEPS_STAT = "timesteps"


@dataclass
class GuidanceOutput:
    """``loss``: scalar, differentiable w.r.t. the images; ``stats``: figures worth logging,
    each a number for the batch or a list of one number per sample (per-sample figures,
    such as ``TIMESTEPS_STAT``: a plant in a group logs its own sample's)."""

    loss: torch.Tensor
    stats: dict[str, float | list[float]] = field(default_factory=dict)


@dataclass
class PendingOutput:
    """A guidance call whose device work may still be running. ``loss`` as in
    ``GuidanceOutput``; ``stats`` in their logged order, each as in ``GuidanceOutput`` or
    a tensor still on the device, 0-dim for the batch or 1-dim per sample (read back
    together, by ``result`` or by the caller)."""

    loss: torch.Tensor
    stats: dict[str, float | list[float] | torch.Tensor] = field(default_factory=dict)

    def device_figures(self) -> torch.Tensor | None:
        """The figures still on the device as one float64 vector (exact for counts and
        timesteps), or None when every figure is already a number."""
        figures = [
            v.detach().double().reshape(-1)
            for v in self.stats.values()
            if isinstance(v, torch.Tensor)
        ]
        return torch.cat(figures) if figures else None

    def with_figures(self, values: Sequence[float]) -> GuidanceOutput:
        """The output, with ``values`` (``device_figures``'s, read back) in their places:
        a number for each 0-dim figure, a list for each per-sample one."""
        stats: dict[str, float | list[float]] = {}
        at = 0
        for key, value in self.stats.items():
            if not isinstance(value, torch.Tensor):
                stats[key] = value
            elif value.dim() == 0:
                stats[key], at = float(values[at]), at + 1
            else:
                stats[key] = [float(x) for x in values[at : at + value.numel()]]
                at += value.numel()
        return GuidanceOutput(loss=self.loss, stats=stats)

    def result(self) -> GuidanceOutput:
        """The output; waits for the device (one copy for all figures)."""
        figures = self.device_figures()
        return self.with_figures([] if figures is None else figures.tolist())


@runtime_checkable
class Guidance(Protocol):
    @property
    def needs_depth(self) -> bool: ...

    @property
    def resolution(self) -> int | None: ...

    @property
    def generator(self) -> torch.Generator | None: ...

    def __call__(
        self,
        images: torch.Tensor,
        depth_cond: torch.Tensor | None,
        cameras: Sequence[Camera],
        step: int,
    ) -> GuidanceOutput: ...


def check_images(images: torch.Tensor, cameras: Sequence[Camera]) -> None:
    """InputError unless ``images`` is a float [B, H, W, 3] batch with one camera per image."""
    if images.dim() != 4 or images.shape[-1] != 3:
        raise InputError(f"images must be [B, H, W, 3], got {list(images.shape)}")
    if not images.is_floating_point():
        raise InputError(f"images must be floating point, got {images.dtype}")
    if len(cameras) != images.shape[0]:
        raise InputError(f"got {len(cameras)} cameras for {images.shape[0]} images")


class NoGuidance:
    """A zero loss that still connects to the graph (ablations: geometry-only runs)."""

    needs_depth = False
    resolution = None
    generator = None

    def __call__(
        self,
        images: torch.Tensor,
        depth_cond: torch.Tensor | None,
        cameras: Sequence[Camera],
        step: int,
    ) -> GuidanceOutput:
        check_images(images, cameras)
        return GuidanceOutput(loss=0.0 * images.sum(), stats={"loss": 0.0})


class PhotometricGuidance:
    """Mean squared error to fixed target images [B, H, W, 3] (tests, ablations, fitting).

    With a single target image and several renders, the target is broadcast.
    """

    needs_depth = False
    resolution = None
    generator = None

    def __init__(self, targets: torch.Tensor):
        if targets.dim() == 3:
            targets = targets[None]
        if targets.dim() != 4 or targets.shape[-1] != 3:
            raise InputError(f"targets must be [B, H, W, 3], got {list(targets.shape)}")
        self.targets = targets.detach().float()

    def __call__(
        self,
        images: torch.Tensor,
        depth_cond: torch.Tensor | None,
        cameras: Sequence[Camera],
        step: int,
    ) -> GuidanceOutput:
        check_images(images, cameras)
        targets = self.targets.to(images.device)
        if targets.shape[1:] != images.shape[1:] or targets.shape[0] not in (1, images.shape[0]):
            raise InputError(
                f"targets {list(targets.shape)} do not match images {list(images.shape)}"
            )
        loss = torch.mean((images - targets) ** 2)
        return GuidanceOutput(loss=loss, stats={"loss": float(loss.detach())})
