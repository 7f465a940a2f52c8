"""The label files of a whole dataset folder (``DIR/plants/<id>/``), split by plant:

- ``splits.json``: the seed, the ratios and the plant ids of each split;
- ``coco/{train,val,test}.json``: COCO files whose ``file_name`` is relative to ``DIR``
  (``plants/<id>/renders/view_000.png``), image and annotation ids unique per file;
- ``yolo/images/<split>/<id>__view_000.png`` (hard links to the renders),
  ``yolo/labels/<split>/<id>__view_000.txt`` and ``yolo/data.yaml``;
- ``gallery.png``, the contact sheet (``exports.gallery``).

A plant counts once its ``run.json`` is written (the last file of a run).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

from plantdreamer import atomic
from plantdreamer.errors import InputError
from plantdreamer.exports import yolo
from plantdreamer.exports.coco import CocoBuilder
from plantdreamer.exports.instances import MIN_INSTANCE_AREA, PlantClasses
from plantdreamer.exports.plant import COCO_FILE, LabelReport, plant_views, write_plant_exports
from plantdreamer.exports.splits import DEFAULT_RATIOS, DEFAULT_SEED, SPLITS, split_plants

PLANTS_DIR = "plants"  # a dataset's plant folders (dataset/runner.py writes them)
SPLITS_FILE = "splits.json"


@dataclass(frozen=True)
class PlantEntry:
    id: str
    folder: Path
    species: str  # the L-System species, or the point cloud's file name


@dataclass(frozen=True)
class LabelOptions:
    """How a dataset's label files are made (the options of ``dataset`` and ``labels``)."""

    ratios: tuple[float, float, float] = DEFAULT_RATIOS
    seed: int = DEFAULT_SEED
    min_area: int = MIN_INSTANCE_AREA


@dataclass(frozen=True)
class DatasetLabels:
    splits: dict[str, list[str]]
    report: LabelReport
    gallery: Path


def finished_plants(dataset_dir: Path) -> list[PlantEntry]:
    """The plants of a dataset folder whose run finished, sorted by id."""
    plants = []
    for run_json in sorted((Path(dataset_dir) / PLANTS_DIR).glob("*/run.json")):
        plants.append(PlantEntry(run_json.parent.name, run_json.parent, plant_species(run_json)))
    return plants


def plant_species(run_json: Path) -> str:
    from plantdreamer.pipeline.config import from_record

    try:
        source = from_record(json.loads(run_json.read_text()).get("config", {})).source
    except (InputError, TypeError, AttributeError, ValueError, OSError):
        return "?"  # a damaged run.json names no species; the plant is still shown
    if source.species:
        return str(source.species)
    return Path(str(source.pointcloud or "?")).name


def write_dataset_exports(dataset_dir: Path, options: LabelOptions | None = None) -> DatasetLabels:
    """Writes the dataset's splits, COCO and YOLO files and gallery; a plant whose own
    label files were made with another area limit gets them remade with this one."""
    options = options or LabelOptions()
    ratios, seed, min_area = options.ratios, options.seed, options.min_area
    dataset_dir = Path(dataset_dir)
    plants = finished_plants(dataset_dir)
    if not plants:
        raise InputError(f"{dataset_dir} has no finished plant under {PLANTS_DIR}/")
    classes = {p.id: _classes(p) for p in plants}
    labelled = [p for p in plants if classes[p.id]]
    for p in labelled:
        if _plant_min_area(p.folder) != min_area:
            write_plant_exports(p.folder, min_area)
    names: dict[int, str] = {}
    for p in labelled:
        names.update({v: n for v, n in classes[p.id].items() if v not in names})
    splits = split_plants([p.id for p in plants], ratios, seed)
    atomic.write_json(
        dataset_dir / SPLITS_FILE,
        {"seed": seed, "ratios": dict(zip(SPLITS, ratios, strict=True)), **splits},
    )
    by_id = {p.id: p for p in labelled}
    index = yolo.class_index(names)
    yolo_dir = dataset_dir / "yolo"
    for split in SPLITS:  # stale links and labels of plants that moved split
        shutil.rmtree(yolo_dir / "images" / split, ignore_errors=True)
        shutil.rmtree(yolo_dir / "labels" / split, ignore_errors=True)
    total = LabelReport()
    for split in SPLITS:
        coco = CocoBuilder(names)
        report = LabelReport()
        for plant_id in splits[split]:
            if plant_id not in by_id:
                continue
            folder = by_id[plant_id].folder
            for frame, objects in plant_views(folder, min_area):
                image = Path(frame["file_path"])
                relative = (folder / image).relative_to(dataset_dir).as_posix()
                coco.add(relative, objects, plant_id=plant_id)
                flat = f"{plant_id}__{image.stem}"
                yolo.link_image(folder / image, yolo_dir / "images" / split / f"{flat}.png")
                lines = yolo.label_lines(objects, index)
                yolo.write_labels(yolo_dir / "labels" / split / f"{flat}.txt", lines)
                report += LabelReport(1, len(objects.areas), objects.dropped)
        (yolo_dir / "images" / split).mkdir(parents=True, exist_ok=True)
        (dataset_dir / "coco").mkdir(exist_ok=True)
        coco.write(dataset_dir / "coco" / f"{split}.json", report.info(f"{split} split", min_area))
        total += report
    yolo.write_data_yaml(yolo_dir / "data.yaml", {s: f"images/{s}" for s in SPLITS}, names)
    from plantdreamer.exports.gallery import write_gallery  # it reads this module's listing

    return DatasetLabels(splits, total, write_gallery(dataset_dir))


def _plant_min_area(folder: Path) -> int | None:
    try:
        return int(json.loads((folder / COCO_FILE).read_text())["info"]["min_instance_area"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _classes(plant: PlantEntry) -> dict[int, str]:
    try:
        return PlantClasses.read(plant.folder).names
    except InputError:
        return {}
