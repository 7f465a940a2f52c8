"""``make_scene``: finished plant folders standing together (a tray, a bench), rendered with
their labels into a scene folder; no plant is trained again.

``scene.json`` (written last) records the plants (their folders and ``run.json`` hashes),
where each stands, its instance-id offset, the settings and the seed.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer import settings
from plantdreamer.errors import InputError
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.scenes.compose import compose, read_plant
from plantdreamer.scenes.config import SCENE_RESOLUTION, VIEW_SETTINGS, SceneConfig
from plantdreamer.scenes.layout import tray_positions
from plantdreamer.scenes.render import SCENE_FILE, SCENE_OUTPUTS, render_scene

LAYOUT_STREAM = 0x74726179  # "tray": the random layout's stream, apart from the views'


@dataclass(frozen=True)
class SceneResult:
    folder: Path
    plants: int
    views: int


def scene_settings(values: Mapping[str, Any]) -> tuple[SceneConfig, GenerateConfig]:
    """A scene's settings by name (``_`` for ``-``): its own (``SceneConfig``) and its
    views' (``VIEW_SETTINGS``, generate's names and limits); any other is refused."""
    own = settings.by_name(SceneConfig)
    given = {settings.canonical(k): v for k, v in values.items()}
    unknown = sorted(set(given) - set(own) - set(VIEW_SETTINGS))
    if unknown:
        raise InputError(
            f"{', '.join(unknown)}: not a setting of a scene (its own: {', '.join(own)}; its "
            f"views': {', '.join(VIEW_SETTINGS)})"
        )
    scene = SceneConfig(**{own[k].path[0]: v for k, v in given.items() if k in own})
    views = {k: v for k, v in given.items() if k not in own}
    if views.get("resolution") is None:
        views["resolution"] = SCENE_RESOLUTION
    cfg = GenerateConfig.from_settings(views)
    try:
        settings.check_types(scene)
        settings.check_choices(scene)
        settings.check_types(cfg)
        settings.check_choices(cfg)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    scene.validate()
    cfg.outputs.validate()
    if not 0.0 <= cfg.train.background <= 1.0:
        raise InputError(f"background must be a grey level in [0, 1], got {cfg.train.background}")
    if cfg.train.render_size > 8192 or cfg.train.render_size < 8:
        raise InputError(f"resolution must be in 8..8192, got {cfg.train.render_size}")
    return scene, cfg


def make_scene(
    plants: Sequence[str | Path],
    out: str | Path,
    *,
    overwrite: bool = False,
    record: Mapping[str, Any] | None = None,
    **values: Any,
) -> SceneResult:
    """Renders the finished plant folders ``plants`` together into ``out``: standing at
    the places of ``scene-layout`` (``scene-spacing`` apart), seen by the views of the
    settings given (generate's names: ``rig``, ``eval-views``, ``background-images``, ...;
    ``seed`` draws the layout and the views). ``record``: more keys of ``scene.json``."""
    from plantdreamer.output_folder import claim_folder

    scene_cfg, cfg = scene_settings(values)
    if not plants:
        raise InputError("a scene needs at least one plant folder")
    read = [read_plant(p) for p in plants]
    spacing = scene_cfg.scene_spacing or max(p.width for p in read)
    rng = np.random.default_rng([cfg.seed, LAYOUT_STREAM])
    places = tray_positions(len(read), scene_cfg.scene_layout, spacing, rng)
    composed = compose(read, places)
    out = Path(out)
    inputs = [p.folder / "plant.ply" for p in read]
    with claim_folder(out, overwrite=overwrite, owned=SCENE_OUTPUTS, inputs=inputs):
        views = render_scene(composed, out, cfg)
        summary = {
            "plants": [
                {
                    "folder": str(p.folder),
                    "place": composed.places[k].tolist(),
                    "instance_offset": composed.instance_offsets[k],
                    "run_sha256": _digest(p.folder / "run.json"),
                }
                for k, p in enumerate(read)
            ],
            "spacing": spacing,
            "settings": {**settings_of(scene_cfg), **_view_settings(cfg)},
            **(record or {}),
        }
        from plantdreamer.atomic import write_text

        write_text(out / SCENE_FILE, json.dumps(summary, indent=2) + "\n")
    return SceneResult(out, len(read), views)


def settings_of(scene: SceneConfig) -> dict[str, Any]:
    return {s.name: settings.value_at(scene, s.path) for s in settings.walk(SceneConfig)}


def _view_settings(cfg: GenerateConfig) -> dict[str, Any]:
    every = cfg.to_dict()
    return {name: every[name] for name in VIEW_SETTINGS}


def _digest(path: Path) -> str:
    from plantdreamer.digests import file_digest

    return file_digest(path)
