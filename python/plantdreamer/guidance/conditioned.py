"""A guidance together with its depth conditioning: the trainer hands it a render and a
camera; the depth map the ControlNet needs is made here, from a ``render_depth(camera)``
callback, cleaned by the section's ``depth_rule`` / ``control_resize`` at the guidance's own
``resolution``, and computed one step ahead on a worker thread (``depth_ahead.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from typing import Any

import torch

from plantdreamer.cameras import Camera
from plantdreamer.errors import InputError
from plantdreamer.guidance.base import Guidance, GuidanceOutput
from plantdreamer.guidance.depth import DepthCleaning, DepthConditioner
from plantdreamer.guidance.depth_ahead import DepthAhead

RenderDepth = Callable[[Camera], tuple[torch.Tensor, torch.Tensor]]
Timer = Callable[[str], AbstractContextManager[Any]]


class ConditionedGuidance:
    """``guidance`` with the depth conditioning it needs (none when ``needs_depth`` is False).

    ``next_camera()`` names the camera of the following step, so its depth map is ready when
    that step comes (``ahead=False`` computes each in line: the same bits).
    """

    def __init__(
        self,
        guidance: Guidance,
        render_depth: RenderDepth,
        next_camera: Callable[[], Camera],
        *,
        depth_rule: str = "stretch",
        control_resize: str = "bilinear",
        ahead: bool = True,
    ) -> None:
        self.guidance = guidance
        self._depth: DepthAhead | None = None
        if guidance.needs_depth:
            size = guidance.resolution
            if size is None:
                raise InputError("a guidance that needs depth must say its resolution")
            cleaning = DepthCleaning(rule=depth_rule, resize=control_resize)
            conditioner = DepthConditioner(render_depth, out_size=size, config=cleaning)
            self._depth = DepthAhead(conditioner, next_camera, ahead)

    def __call__(
        self, image: torch.Tensor, camera: Camera, step: int, more: bool, timer: Timer | None = None
    ) -> GuidanceOutput:
        """The guidance of ``image`` (rendered from ``camera``) at ``step``; ``more``: another
        step follows (so its depth map may be started)."""
        timed = timer or (lambda name: nullcontext())
        depth = None
        if self._depth is not None:
            with timed("depth"):
                depth = self._depth.get(camera, more=more)
        with timed("guidance"):
            return self.guidance(image, depth, [camera], step)

    def close(self) -> None:
        if self._depth is not None:
            self._depth.close()
