"""A guidance without networks, for measuring the host's own work per step
(``bench_throughput.py --networks stub``): the loss is a fixed linear function of the
renders, so every render gets the same deterministic gradient (a fixed pattern drawn once
from the seed) whatever the step, and the depth conditioning a ControlNet would read is
still made at ``resolution`` (``needs_depth``), as with the real networks."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from plantdreamer.cameras import Camera
from plantdreamer.guidance.base import GuidanceOutput, check_images

# The pattern's scale: small next to a render's values, so the plants change slowly.
GRADIENT_SCALE = 1e-3


class StubGuidance:
    def __init__(self, resolution: int, seed: int = 0, needs_depth: bool = True) -> None:
        """``needs_depth=False`` leaves the depth conditioning out too (what it costs the
        host: ``bench_throughput.py --stub-depth on off``)."""
        self.needs_depth = needs_depth
        self.resolution = resolution
        self.seed = seed
        # Checkpoints hold a guidance's generator state; this one never draws from it.
        self.generator = torch.Generator().manual_seed(seed)
        self._patterns: dict[tuple[int, ...], torch.Tensor] = {}

    def _pattern(self, shape: tuple[int, ...]) -> torch.Tensor:
        if shape not in self._patterns:
            draw = torch.Generator().manual_seed(self.seed)
            self._patterns[shape] = GRADIENT_SCALE * torch.randn(shape, generator=draw)
        return self._patterns[shape]

    def __call__(
        self,
        images: torch.Tensor,
        depth_cond: torch.Tensor | None,
        cameras: Sequence[Camera],
        step: int,
    ) -> GuidanceOutput:
        check_images(images, cameras)
        pattern = self._pattern(tuple(images.shape[1:])).to(images.device)
        # A mean over the batch, as the real guidance's loss: each render's gradient is
        # the pattern / B (the step scales the loss by B).
        loss = (images * pattern).sum() / images.shape[0]
        return GuidanceOutput(loss=loss, stats={"loss": float(loss.detach())})
