"""The label files of one plant folder, made from what ``generate`` (or ``render --labels``)
wrote there: ``coco.json``, ``yolo/`` (``images/`` hard-linked to ``renders/``, ``labels/``,
``data.yaml``), ``points.ply``, and ``ply_file_path`` in ``transforms.json``.

Everything here is derived from the folder's PNGs and ``plant.ply``, so it can be remade at
any time (``plantdreamer labels DIR --min-instance-area N``) and is the same bytes from the
same folder.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from plantdreamer import atomic
from plantdreamer.exports import yolo
from plantdreamer.exports.coco import CocoBuilder
from plantdreamer.exports.instances import (
    MIN_INSTANCE_AREA,
    PlantClasses,
    ViewObjects,
    labelled_frames,
    read_transforms,
    read_view_objects,
)
from plantdreamer.exports.points import write_points_ply

POINTS_FILE = "points.ply"
COCO_FILE = "coco.json"
YOLO_DIR = "yolo"
LABEL_FILES = (POINTS_FILE, COCO_FILE, YOLO_DIR)  # what write_plant_exports writes


@dataclass(frozen=True)
class LabelReport:
    """What the label files hold: images, objects written, objects under the area limit."""

    images: int = 0
    objects: int = 0
    dropped: int = 0

    def info(self, what: str, min_area: int) -> dict[str, object]:
        """The ``info`` record of a COCO file."""
        return {
            "description": f"plantdreamer labels of {what}",
            "min_instance_area": min_area,
            "objects": self.objects,
            "objects_left_out": self.dropped,
        }

    def __add__(self, other: LabelReport) -> LabelReport:
        return LabelReport(
            self.images + other.images, self.objects + other.objects, self.dropped + other.dropped
        )


def plant_views(plant_dir: Path, min_area: int) -> Iterator[tuple[dict, ViewObjects]]:
    """Each labelled frame of a plant folder with its objects."""
    for frame in labelled_frames(plant_dir):
        yield frame, read_view_objects(plant_dir, frame, min_area)


def write_plant_exports(plant_dir: Path, min_area: int = MIN_INSTANCE_AREA) -> LabelReport:
    """Writes the point cloud and, for a labelled plant, its COCO and YOLO files."""
    plant_dir = Path(plant_dir)
    if (plant_dir / "plant.ply").is_file():
        write_points_ply(plant_dir / "plant.ply", plant_dir / POINTS_FILE)
        _name_point_cloud(plant_dir)
    if not (plant_dir / "transforms.json").is_file():  # no view rendered (--eval-views 0)
        return LabelReport()
    if not read_transforms(plant_dir).get("semantic_classes"):  # no labels
        return LabelReport()
    names = PlantClasses.read(plant_dir).names
    index = yolo.class_index(names)
    coco = CocoBuilder(names)
    report = LabelReport()
    for frame, objects in plant_views(plant_dir, min_area):
        image = Path(frame["file_path"])
        coco.add(image.as_posix(), objects)
        yolo.link_image(plant_dir / image, plant_dir / YOLO_DIR / "images" / image.name)
        labels = plant_dir / YOLO_DIR / "labels" / f"{image.stem}.txt"
        yolo.write_labels(labels, yolo.label_lines(objects, index))
        report += LabelReport(1, len(objects.areas), objects.dropped)
    yolo.write_data_yaml(
        plant_dir / YOLO_DIR / "data.yaml", {"train": "images", "val": "images"}, names
    )
    coco.write(plant_dir / COCO_FILE, report.info(f"plant {plant_dir.name}", min_area))
    return report


def _name_point_cloud(plant_dir: Path) -> None:
    """Names points.ply as transforms.json's ``ply_file_path`` (nerfstudio's key for the
    initial points of splatfacto, relative to the transforms.json folder)."""
    path = plant_dir / "transforms.json"
    if not path.is_file():
        return
    meta = read_transforms(plant_dir)
    if meta.get("ply_file_path") == POINTS_FILE:
        return
    meta["ply_file_path"] = POINTS_FILE
    atomic.write_text(path, json.dumps(meta, indent=2) + "\n")
