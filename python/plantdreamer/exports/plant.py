"""The label files of one plant folder, made from what ``generate`` (or ``render --labels``)
wrote there: ``coco.json``, ``yolo/`` (``images/`` hard-linked to ``renders/``, ``labels/``,
``data.yaml``), ``points.ply``, ``counts.csv`` (each view's visible leaves and plant size
in pixels, also in COCO's image records; ``exports.figures``), and ``ply_file_path`` in
``transforms.json``.

Everything here is derived from the folder's PNGs and ``plant.ply``, so it can be remade at
any time (``plantdreamer labels DIR --min-instance-area N``) and is the same bytes from the
same folder.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

from plantdreamer import atomic
from plantdreamer.exports import yolo
from plantdreamer.exports.classes import DatasetClasses, dataset_classes
from plantdreamer.exports.coco import CocoBuilder
from plantdreamer.exports.figures import plant_records, read_view_traits
from plantdreamer.exports.instances import (
    MIN_INSTANCE_AREA,
    PlantClasses,
    ViewObjects,
    labelled_frames,
    read_transforms,
)
from plantdreamer.exports.points import write_points_ply
from plantdreamer.output_folder import tree
from plantdreamer.traits.counts import COUNTS_FILE, write_counts

POINTS_FILE = "points.ply"
COCO_FILE = "coco.json"
YOLO_DIR = "yolo"
VIEW_PNG = re.compile(r"view_\d{3,}\.png")  # a view's picture: renders/, labels/, yolo/
# What write_plant_exports writes (output_folder.Owned).
LABEL_FILES = (
    POINTS_FILE,
    COCO_FILE,
    COUNTS_FILE,
    *tree(
        YOLO_DIR,
        "data.yaml",
        *tree("images", VIEW_PNG),
        *tree("labels", re.compile(r"view_\d{3,}\.txt")),
    ),
)
PLANT = ""  # the one plant of a plant folder's class table
# COCOeval's maxDets, torchvision's box_detections_per_img and Detectron2's
# TEST.DETECTIONS_PER_IMAGE all default to 100.
DEFAULT_MAX_DETECTIONS = 100


@dataclass(frozen=True)
class LabelReport:
    """What the label files hold: images, objects written, ignore regions (objects under
    the area limit), instances without a class (left out), and the most objects in one
    image (what COCOeval's ``maxDets`` and a detector's detections per image must reach)."""

    images: int = 0
    objects: int = 0
    ignored: int = 0
    unclassed: int = 0
    max_objects: int = 0

    @classmethod
    def of(cls, objects: ViewObjects) -> LabelReport:
        """The report of one view."""
        return cls(1, objects.objects, objects.ignored, objects.unclassed, objects.objects)

    def info(self, what: str, min_area: int, stuff: tuple[str, ...] = ()) -> dict[str, object]:
        """The ``info`` record of a COCO file."""
        return {
            "description": f"plantdreamer labels of {what}",
            "min_instance_area": min_area,
            "stuff_classes": list(stuff),
            "objects": self.objects,
            "ignore_regions": self.ignored,
            "instances_without_class": self.unclassed,
            "max_objects_per_image": self.max_objects,
        }

    def describe(self, min_area: int) -> str:
        """The objects part of a summary line."""
        line = (
            f"{self.objects} objects in {self.images} images, at most {self.max_objects} in "
            f"one ({self.ignored} under {min_area} pixels kept as ignore regions"
        )
        if self.unclassed:
            line += f"; {self.unclassed} instances without a class left out"
        line += ")"
        if self.max_objects > DEFAULT_MAX_DETECTIONS:
            line += (
                f"; more than {DEFAULT_MAX_DETECTIONS} objects in an image: raise COCOeval's "
                f"maxDets and the detector's detections per image (docs/datasets.md)"
            )
        return line

    def __add__(self, other: LabelReport) -> LabelReport:
        return LabelReport(
            self.images + other.images,
            self.objects + other.objects,
            self.ignored + other.ignored,
            self.unclassed + other.unclassed,
            max(self.max_objects, other.max_objects),
        )


@dataclass(frozen=True)
class PlantView:
    """A labelled view of a plant folder: its image id (COCO's and the torch Dataset's) and
    frame of transforms.json."""

    image_id: int
    frame: dict


def plant_views(plant_dir: Path) -> list[PlantView]:
    """The labelled frames of a plant folder, numbered from 1 in their order."""
    return [PlantView(i + 1, f) for i, f in enumerate(labelled_frames(plant_dir))]


def plant_classes(plant_dir: Path) -> DatasetClasses:
    """A plant folder's classes as categories (its values; unnamed values unlabelled)."""
    return dataset_classes({PLANT: PlantClasses.read(plant_dir).names})


def write_plant_exports(
    plant_dir: Path, min_area: int = MIN_INSTANCE_AREA, stuff: tuple[str, ...] = ()
) -> LabelReport:
    """Writes the point cloud and, for a labelled plant, its COCO and YOLO files (``stuff``:
    the names of classes that are no objects there)."""
    plant_dir = Path(plant_dir)
    if (plant_dir / "plant.ply").is_file():
        write_points_ply(plant_dir / "plant.ply", plant_dir / POINTS_FILE)
        _name_point_cloud(plant_dir)
    if not (plant_dir / "transforms.json").is_file():  # no view rendered (--eval-views 0)
        return LabelReport()
    if not read_transforms(plant_dir).get("semantic_classes"):  # no labels
        return LabelReport()
    classes = plant_classes(plant_dir)
    stuff_ids, things = classes.stuff_ids(stuff), classes.things(stuff)
    index = yolo.class_index(things)
    coco = CocoBuilder(things)
    report = LabelReport()
    recorded, counts = plant_records(plant_dir), []
    for view in plant_views(plant_dir):
        lut = classes.luts[PLANT]
        seen = read_view_traits(plant_dir, view.frame, min_area, lut, classes.names,
                                stuff_ids, recorded)  # fmt: skip
        objects = seen.objects
        image = Path(view.frame["file_path"])
        coco.add(view.image_id, image.as_posix(), objects, seen.per_object, **seen.fields)
        counts.append({"file_name": image.as_posix(), **seen.fields})
        yolo.link_image(plant_dir / image, plant_dir / YOLO_DIR / "images" / image.name)
        labels = plant_dir / YOLO_DIR / "labels" / f"{image.stem}.txt"
        yolo.write_labels(labels, yolo.label_lines(objects, index))
        report += LabelReport.of(objects)
    yolo.write_data_yaml(
        plant_dir / YOLO_DIR / "data.yaml", {"train": "images", "val": "images"}, things
    )
    coco.write(plant_dir / COCO_FILE, report.info(f"plant {plant_dir.name}", min_area, stuff))
    write_counts(plant_dir / COUNTS_FILE, ("file_name",), counts)
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
