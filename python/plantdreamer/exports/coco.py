"""COCO instance segmentation JSON, written with pycocotools (the library that defines the
format's masks).

One image per labelled view; one annotation per object (``exports.instances``), with its
mask as compressed RLE (``pycocotools.mask.encode``), its box ``[x, y, width, height]`` and
area from the same library, ``iscrowd`` 0, and ``iscrowd`` 1 for an ignore region (an
object under the area limit). Category ids are the dataset's class ids
(``exports.classes``: the class pixel values of ``labels/`` unless plants disagree), so a
COCO category, a class map pixel and a YOLO class (its index in ``data.yaml``'s order) name
the same thing. Image ids are given by the caller (``exports.views``: the ids the torch
Dataset's targets carry); annotation ids come from a counter the caller may share between
files, so the files of a dataset's splits can be merged as they are.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer import atomic
from plantdreamer.exports.instances import ViewObjects


@dataclass
class CocoBuilder:
    """Collects images and annotations; ``image_root``-relative file names."""

    categories: dict[int, str]
    annotation_ids: Iterator[int] = field(default_factory=lambda: itertools.count(1))
    images: list[dict[str, Any]] = field(default_factory=list)
    annotations: list[dict[str, Any]] = field(default_factory=list)
    licenses: list[dict[str, Any]] = field(default_factory=list)  # COCO's "licenses"

    def add(
        self,
        image_id: int,
        file_name: str,
        objects: ViewObjects,
        per_object: list[dict[str, Any]] | None = None,
        **extra: Any,
    ) -> None:
        """One image and its objects (``per_object``: more keys of each object's
        annotation; ``extra``: more keys of the image record)."""
        from pycocotools import mask as mask_utils

        h, w = objects.shape
        self.images.append(
            {"id": image_id, "file_name": file_name, "height": h, "width": w, **extra}
        )
        if not len(objects.masks):
            return
        # [K, W, H] in C order is [H, W, K] in Fortran order, as encode wants it.
        columns = np.ascontiguousarray(objects.masks.view(np.uint8).transpose(0, 2, 1))
        rles = mask_utils.encode(columns.transpose(2, 1, 0))
        boxes = mask_utils.toBbox(rles)
        areas = mask_utils.area(rles)
        for k, rle in enumerate(rles):
            self.annotations.append(
                {
                    "id": next(self.annotation_ids),
                    "image_id": image_id,
                    "category_id": int(objects.categories[k]),
                    "segmentation": {"size": [h, w], "counts": rle["counts"].decode()},
                    "area": int(areas[k]),
                    "bbox": [float(v) for v in boxes[k]],
                    "iscrowd": int(objects.iscrowd[k]),
                    "instance_id": int(objects.instance_ids[k]),
                    **(per_object[k] if per_object else {}),
                }
            )

    def to_dict(self, info: dict[str, Any]) -> dict[str, Any]:
        return {
            "info": info,
            **({"licenses": self.licenses} if self.licenses else {}),
            "images": self.images,
            "annotations": self.annotations,
            "categories": [
                {"id": v, "name": name, "supercategory": "plant"}
                for v, name in sorted(self.categories.items())
            ],
        }

    def write(self, path: Path, info: dict[str, Any]) -> None:
        atomic.write_json(path, self.to_dict(info))
