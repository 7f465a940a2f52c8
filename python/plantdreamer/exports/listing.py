"""The plants of a dataset folder (``DIR/plants/<id>/``) whose run finished, with their
species: what the dataset's label files, its gallery and the torch Dataset list.

A plant counts once its ``run.json`` is written (the last file of a run).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

PLANTS_DIR = "plants"  # a dataset's plant folders (dataset/runner.py writes them)
SCENES_DIR = "scenes"  # a dataset's scenes (dataset/scenes.py writes them)
SCENE_RECORD = "scene.json"  # a scene's last file: written, the scene is finished


@dataclass(frozen=True)
class PlantEntry:
    id: str
    folder: Path
    species: str  # the L-System species, or the point cloud's file name


def finished_plants(dataset_dir: Path) -> list[PlantEntry]:
    """The plants of a dataset folder whose run finished, sorted by id."""
    plants = []
    for run_json in sorted((Path(dataset_dir) / PLANTS_DIR).glob("*/run.json")):
        plants.append(PlantEntry(run_json.parent.name, run_json.parent, plant_species(run_json)))
    return plants


def finished_scenes(dataset_dir: Path) -> list[PlantEntry]:
    """The scenes of a dataset folder that were finished (their ``scene.json`` written),
    sorted by id; their species is ``scene``."""
    records = sorted((Path(dataset_dir) / SCENES_DIR).glob(f"*/{SCENE_RECORD}"))
    return [PlantEntry(r.parent.name, r.parent, "scene") for r in records]


def scene_record(scene: PlantEntry) -> dict:
    """A scene's ``scene.json`` ({} when unreadable)."""
    try:
        record = json.loads((scene.folder / SCENE_RECORD).read_text())
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


def plant_species(run_json: Path) -> str:
    """The ``species`` setting a run recorded, else its ``pointcloud``'s file name; "?" for
    a record that names neither. Records keep settings by name (``pipeline.settings.config``); those
    of the sectioned versions kept these two under ``source``."""
    try:
        config = json.loads(run_json.read_text()).get("config", {})
        section = config.get("source", config)
        species, cloud = section.get("species"), section.get("pointcloud")
    except (OSError, ValueError, AttributeError):
        return "?"
    return species_name(species, cloud)


def species_name(species: str | None, pointcloud: str | None) -> str:
    """What a dataset calls a plant's species (its splits and card count by it): the
    L-System species, else its point cloud's file name; "?" for neither."""
    if species:
        return str(species)
    return Path(str(pointcloud or "?")).name
