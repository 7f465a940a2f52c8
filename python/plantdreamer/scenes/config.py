"""The settings of a scene (several finished plants together, as on a tray or a bench), and
which of generate's settings its views take: a scene is rendered, never trained, so only
the settings of the exported views apply (their rig, background, jitter, count, size)."""

from __future__ import annotations

from dataclasses import dataclass

from plantdreamer.errors import InputError
from plantdreamer.settings import setting, walk
from plantdreamer.views import ViewsConfig

LAYOUTS = ("grid", "random")
MAX_SCENE_PLANTS = 64
# generate's settings that a scene's views take (the rest describe training).
VIEW_SETTINGS = (
    "eval-views", "eval-distance", "eval-elevation-deg", "eval-fovy-deg", "resolution",
    "background", "turntable", "turntable-frames", "scene-size", "seed",
    *(s.name for s in walk(ViewsConfig)),
)  # fmt: skip
SCENE_RESOLUTION = 512  # a scene's render size when none is given (render's, on the CPU)


@dataclass
class SceneConfig:
    """Where a scene's plants stand."""

    scene_plants: int = setting(
        4, "Plants in each scene (a tray or bench).", range=(1, MAX_SCENE_PLANTS)
    )
    scene_layout: str = setting(
        "grid",
        "Where a scene's plants stand: grid (rows of scene-spacing) or random (seeded places "
        "at least scene-spacing apart).",
        choices=LAYOUTS,
    )
    scene_spacing: float | None = setting(
        None,
        "Distance between the centres of a scene's plants, in the plants' units (metres for "
        "L-System plants).",
        default_text="the widest plant's width",
    )

    def validate(self) -> None:
        spacing = self.scene_spacing
        if spacing is not None and not 0 < spacing < 1e6:
            raise InputError(f"scene-spacing must be in (0, 1e6), got {spacing}")
