"""Label files that trainers load as they are: COCO and YOLO segmentation, seeded splits by
plant, and a coloured, labelled point cloud (docs/datasets.md).

``write_plant_exports`` makes them for one plant folder, ``write_dataset_exports`` for a
dataset folder; both read only what ``generate`` wrote, so they can be remade at any time.
"""

from __future__ import annotations

from plantdreamer.exports.dataset import DatasetLabels, LabelOptions, write_dataset_exports
from plantdreamer.exports.instances import MIN_INSTANCE_AREA, ViewObjects, view_objects
from plantdreamer.exports.plant import LabelReport, write_plant_exports
from plantdreamer.exports.splits import DEFAULT_RATIOS, split_plants

__all__ = [
    "DEFAULT_RATIOS",
    "MIN_INSTANCE_AREA",
    "DatasetLabels",
    "LabelOptions",
    "LabelReport",
    "ViewObjects",
    "split_plants",
    "view_objects",
    "write_dataset_exports",
    "write_plant_exports",
]
