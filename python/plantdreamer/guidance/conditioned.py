"""A guidance together with its depth conditioning, for one plant or a group trained
together: the trainer hands it the renders and their cameras; the depth maps the ControlNet
needs are made here, one source per plant (a ``render_depth(camera)`` callback over that
plant's initial Gaussians), rendered at the guidance's own ``resolution`` (``depth_size``
"sds") or at the training render's and resized (``control_resize``), cleaned by the
section's ``depth_rule``, and computed one step ahead as tasks of the trainer's
host pool (``depth_ahead.py``). The guidance itself is called once per step on each batch the trainer
hands it: the whole group, or one half of it (``guidance/in_flight.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from contextlib import AbstractContextManager, nullcontext
from typing import Any

import torch

from plantdreamer.cameras import Camera
from plantdreamer.errors import InputError
from plantdreamer.guidance.base import Guidance, PendingOutput
from plantdreamer.guidance.config import SDS_DEFAULTS
from plantdreamer.guidance.depth import DepthCleaning, DepthConditioner
from plantdreamer.guidance.depth_ahead import DepthAhead

RenderDepth = Callable[[Camera], tuple[torch.Tensor, torch.Tensor]]
Timer = Callable[[str], AbstractContextManager[Any]]


class ConditionedGuidance:
    """``guidance`` with the depth conditioning it needs (none when ``needs_depth`` is False).

    Plant ``i`` renders its depth with ``render_depths[i]``; ``next_cameras[i]()`` names its
    camera of the following step, so that depth map is made on the ``ahead`` pool while
    this step runs and is ready when the next comes (None computes each in line: the same
    bits).
    """

    def __init__(
        self,
        guidance: Guidance,
        render_depths: Sequence[RenderDepth],
        next_cameras: Sequence[Callable[[], Camera]],
        *,
        depth_rule: str = SDS_DEFAULTS.depth_rule,
        depth_size: str = SDS_DEFAULTS.depth_size,
        control_resize: str = SDS_DEFAULTS.control_resize,
        erosion_distance: str = SDS_DEFAULTS.erosion_distance,
        ahead: Executor | None = None,
    ) -> None:
        self.guidance = guidance
        self._depth: list[DepthAhead] = []
        if guidance.needs_depth:
            size = guidance.resolution
            if size is None:
                raise InputError("a guidance that needs depth must say its resolution")
            cleaning = DepthCleaning(
                rule=depth_rule, resize=control_resize, distance=erosion_distance
            )
            for render_depth, next_camera in zip(render_depths, next_cameras, strict=True):
                conditioner = DepthConditioner(
                    render_depth, out_size=size, config=cleaning, depth_size=depth_size
                )
                self._depth.append(DepthAhead(conditioner, next_camera, ahead))

    @property
    def device(self) -> torch.device:
        """Where the guidance's networks run (the CPU for guidances without networks)."""
        return torch.device(getattr(self.guidance, "device", "cpu"))

    def launch(
        self,
        images: torch.Tensor,
        plants: Sequence[int],
        cameras: Sequence[Camera],
        step: int,
        more: bool,
        timer: Timer | None = None,
    ) -> PendingOutput:
        """The guidance of ``images`` [B, H, W, 3] (plant ``plants[b]`` rendered from
        ``cameras[b]``) at ``step``, launched (``Guidance.launch``) where the guidance
        offers it, else called; ``more``: another step follows."""
        timed = timer or (lambda name: nullcontext())
        depth = None
        if self._depth:
            with timed("depth"):
                maps = [
                    self._depth[i].get(c, more=more) for i, c in zip(plants, cameras, strict=True)
                ]
                depth = torch.cat(maps)
        with timed("guidance.launch"):
            launch = getattr(self.guidance, "launch", None)
            if launch is not None:
                return launch(images, depth, list(cameras), step)
            out = self.guidance(images, depth, list(cameras), step)
            return PendingOutput(out.loss, dict(out.stats))

    def close(self) -> None:
        for depth in self._depth:
            depth.close()
