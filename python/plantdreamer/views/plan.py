"""The plan of a plant's (or a scene's) exported views: each view's camera, background and
jitter, drawn from the seed before any view is rendered, and what each drew (written beside
the view in transforms.json: ``rig``, ``background``, ``jitter``).

``ViewPlan.finish`` turns a view rendered at ``render_background`` into the picture written:
on the orbit with the grey of the renders and no jitter (the default) it is the render
itself, so the files are those of before, byte for byte.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from plantdreamer.camera_rigs import ORBIT, RIGS, TRANSFORMS, draw_rig
from plantdreamer.cameras import Camera
from plantdreamer.gaussians import Gaussians
from plantdreamer.views.backgrounds import Background, composite, draw_background
from plantdreamer.views.config import ViewsConfig
from plantdreamer.views.jitter import Jitter, draw_jitter

LOOK_STREAM = 0x6C6F6F6B  # "look": each view's background and jitter, apart from the rig's
# Renders over photos are written at zlib's fastest level: at Pillow's default (6) a 512 px
# view over a photo took 4x as long to encode as at 1, for files 20% smaller.
PHOTO_PNG = {"compress_level": 1}


@dataclass
class ViewPlan:
    """Cameras and, per view, a background, a jitter and the record of what was drawn."""

    cameras: list[Camera]
    records: list[dict[str, Any]]
    render_background: float  # the grey the rasterizer renders on (0: composited later)
    backgrounds: list[Background | None] = field(default_factory=list)
    jitters: list[Jitter | None] = field(default_factory=list)
    orbit_distance: float | None = None  # the orbit's distance (framed or given); None else
    turns: bool = True  # the views go round the plant at one distance (a turntable of them)
    png: dict[str, Any] = field(default_factory=dict)  # Pillow's options for the renders
    _index: dict[int, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._index = {id(c): i for i, c in enumerate(self.cameras)}

    def index(self, camera: Camera) -> int:
        """The view ``camera`` (one of ``cameras``) is."""
        return self._index[id(camera)]

    def finish(self, view: int, rendered: np.ndarray, alpha: np.ndarray) -> np.ndarray:
        """View ``view``'s picture: its render (float [H, W, 3], made on
        ``render_background``) over its background, then jittered."""
        background = self.backgrounds[view] if self.backgrounds else None
        if background is not None:
            rendered = composite(rendered, alpha, background.image)
        jitter = self.jitters[view] if self.jitters else None
        return rendered if jitter is None else jitter.apply(rendered)


def plan_views(
    config: ViewsConfig,
    scene: Gaussians,
    seed: int,
    views: int,
    fovy_deg: float,
    size: int,
    grey: float,
    orbit: Callable[[], tuple[list[Camera], float | None]],
) -> ViewPlan:
    """The views of ``scene`` (its frame): ``orbit()`` gives the evaluation orbit (and its
    distance) for the orbit rig; ``views``, ``fovy_deg`` and ``size`` are the orbit's count,
    field of view and render size, which the other rigs take unless they set their own."""
    rig = config.rig
    width, height = rig.rig_width or size, rig.rig_height or size
    distance = None
    if rig.rig == ORBIT:
        cameras, distance = orbit()
        records: list[dict[str, Any]] = [{} for _ in cameras]
    elif rig.rig == TRANSFORMS:
        from plantdreamer.views.real_rig import framed_rig

        assert rig.rig_transforms is not None
        cameras = framed_rig(rig.rig_transforms, scene)
        records = [{"rig": {"transforms_frame": i}} for i in range(len(cameras))]
    else:
        drawn = draw_rig(rig.distribution(), scene, views, seed, fovy_deg, width, height)
        cameras, records = drawn.cameras, [{"rig": r} for r in drawn.records]
    turns = rig.rig == ORBIT or (rig.rig in RIGS and rig.distribution().even)
    if config.plain:
        return ViewPlan(cameras, records, grey, orbit_distance=distance, turns=turns)
    backgrounds, jitters = [], []
    for i, (camera, record) in enumerate(zip(cameras, records, strict=True)):
        rng = np.random.default_rng([seed, LOOK_STREAM, i])
        background = draw_background(config.background, rng, camera.width, camera.height)
        jitter = draw_jitter(config.jitter, rng)
        if background is not None:
            record["background"] = background.record
        if jitter is not None:
            record["jitter"] = jitter.record()
        backgrounds.append(background)
        jitters.append(jitter)
    render_background = grey if config.background.plain else 0.0
    png = PHOTO_PNG if config.background.background_images is not None else {}
    return ViewPlan(
        cameras, records, render_background, backgrounds, jitters, distance, turns, dict(png)
    )
