"""A dataset's scenes: each ``[[scene]]`` table of a spec (or ``dataset --scenes``) makes one
scene per seed from the dataset's finished plants, once they are done, into
``DIR/scenes/<name>-s<seed>/`` (``scenes.make_scene``: rendered, never trained).

A scene takes its plants from one split only, the split its own id draws (as a plant's:
``exports.splits``), so no plant of a test scene is trained on; it draws
``scene-plants`` of that split's labelled plants from its seed (all different while the split
has enough, else some twice). Its views take the spec's ``[defaults]`` for the settings of
views (``rig``, ``background-images``, ``eval-views``, ...), under the table's own. A scene
whose settings and plants are those its ``scene.json`` records is kept; any other is made
again. Every table is checked before Ray starts.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer.dataset.spec import NAME_PATTERN
from plantdreamer.errors import InputError
from plantdreamer.exports.dataset import LabelOptions, labelled_plants
from plantdreamer.exports.listing import SCENES_DIR, finished_plants, scene_record
from plantdreamer.exports.splits import split_of
from plantdreamer.scenes import make_scene, scene_settings
from plantdreamer.scenes.config import VIEW_SETTINGS
from plantdreamer.seeds import parse_seeds
from plantdreamer.settings import canonical

POOL_STREAM = 0x706F6F6C  # "pool": which plants a scene draws, apart from its layout and views
SCENE_KEYS = ("name", "seeds")


@dataclass(frozen=True)
class ScenePlan:
    """One scene of a dataset: its id, seed and settings by name (its own and its views')."""

    id: str
    seed: int
    values: dict[str, Any]

    @property
    def plants(self) -> int:
        return scene_settings(self.values)[0].scene_plants


def expand_scenes(spec: dict[str, Any]) -> list[ScenePlan]:
    """The scenes of a spec's ``[[scene]]`` tables, their settings checked."""
    tables = spec.get("scene", [])
    if not isinstance(tables, list):
        raise InputError("spec: 'scene' must be tables ([[scene]])")
    defaults = {canonical(k): v for k, v in spec.get("defaults", {}).items()}
    defaults = {k: v for k, v in defaults.items() if k in VIEW_SETTINGS and k != "seed"}
    scenes: list[ScenePlan] = []
    seen: set[str] = set()
    for index, table in enumerate(tables, 1):
        where = f"scene {index}"
        if not isinstance(table, dict):
            raise InputError(f"spec: {where} must be a table of settings")
        table = {canonical(k): v for k, v in table.items()}
        name = table.get("name", "scene")
        if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
            raise InputError(
                f"spec: {where}: name {name!r} must be 1-100 letters, digits, '-', '_' or '.' "
                "(not first): it names the scenes' folders"
            )
        if "seed" in table:
            raise InputError(f"spec: {where}: give 'seeds' (one scene per seed), not 'seed'")
        seeds = table.get("seeds", "0")
        text = ",".join(map(str, seeds)) if isinstance(seeds, list) else str(seeds)
        values = {**defaults, **{k: v for k, v in table.items() if k not in SCENE_KEYS}}
        for seed in parse_seeds(text, what=f"spec: {where}: 'seeds'"):
            try:
                scene_settings({**values, "seed": seed})
            except InputError as exc:
                raise InputError(f"spec: {where}: {exc}") from None
            scene_id = f"{name}-s{seed:04d}"
            if scene_id in seen:
                raise InputError(f"spec: scene {scene_id!r} appears twice; name the tables")
            seen.add(scene_id)
            scenes.append(ScenePlan(scene_id, seed, {**values, "seed": seed}))
    return scenes


def with_scene_table(spec: dict, seeds: str | None, options: dict) -> dict:
    """The spec with the scenes ``--scenes`` asks for (one more [[scene]] table)."""
    given = {k: v for k, v in options.items() if v is not None}
    if seeds is None:
        if given:
            raise InputError(f"--{next(iter(given))} describes the scenes of --scenes SEEDS")
        return spec
    return {**spec, "scene": [*spec.get("scene", []), {"seeds": seeds, **given}]}


def make_dataset_scenes(
    dataset_dir: Path, scenes: list[ScenePlan], labels: LabelOptions
) -> list[str]:
    """Makes (or keeps) the dataset's scenes; returns warnings (a split with no plant)."""
    from plantdreamer.exports.card import plant_guidance

    if not scenes:
        return []
    plants, _ = labelled_plants(finished_plants(dataset_dir))
    warnings = []
    for scene in scenes:
        split = split_of(scene.id, labels.ratios, labels.seed)
        pool = [p for p in plants if split_of(p.id, labels.ratios, labels.seed) == split]
        if not pool:
            warnings.append(f"scene {scene.id} ({split}) not made: no labelled {split} plant")
            continue
        rng = np.random.default_rng([scene.seed, POOL_STREAM])
        picks = rng.choice(len(pool), scene.plants, replace=len(pool) < scene.plants)
        chosen = [pool[int(i)] for i in picks]
        folder = Path(dataset_dir) / SCENES_DIR / scene.id
        key = _scene_key(scene, [p.folder for p in chosen])
        if scene_record_key(folder) == key:
            continue
        guided = any(plant_guidance(p.folder) == "sds" for p in chosen)
        record = {
            "id": scene.id,
            "split": split,
            "plant_ids": [p.id for p in chosen],
            "guidance": "sds" if guided else "none",
            "key": key,
        }
        folder.parent.mkdir(parents=True, exist_ok=True)
        make_scene([p.folder for p in chosen], folder, overwrite=True, record=record,
                   **scene.values)  # fmt: skip
    return warnings


def scene_record_key(folder: Path) -> str | None:
    from plantdreamer.exports.listing import PlantEntry

    key = scene_record(PlantEntry(folder.name, folder, "scene")).get("key")
    return key if isinstance(key, str) else None


def _scene_key(scene: ScenePlan, folders: list[Path]) -> str:
    """What a scene is made of: its settings and its plants' records."""
    from plantdreamer.digests import file_digest

    text = json.dumps(scene.values, sort_keys=True, default=str)
    text += "".join(f"|{f.name}:{file_digest(f / 'run.json')}" for f in folders)
    return hashlib.sha256(text.encode()).hexdigest()[:16]
