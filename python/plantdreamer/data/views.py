"""``PlantViews``: the labelled views of a plant folder or a dataset folder as a torch
``Dataset`` whose items torchvision's detection and segmentation models take as they are.

Each item is ``(image, target)``:

- ``image``: float32 [3, H, W] in [0, 1] (a ``tv_tensors.Image`` when torchvision is there);
- ``target["boxes"]``: float32 [K, 4] x0 y0 x1 y1, pixel edges, never zero-sized
  (``tv_tensors.BoundingBoxes``, XYXY);
- ``target["labels"]``: int64 [K], the class pixel values (1..; 0 is background, so
  ``num_classes`` = largest value + 1 for Mask R-CNN);
- ``target["masks"]``: uint8 [K, H, W] (``tv_tensors.Mask``);
- ``target["semantic"]``: int64 [H, W] class map (0 background), ready for a cross-entropy;
- ``target["instance_ids"]``, ``target["area"]``, ``target["iscrowd"]``, ``target["image_id"]``.

Objects under ``min_area`` pixels are left out (``exports.instances``), as in the COCO and
YOLO files. The 16-bit instance PNGs never reach the user: torch has few uint16 kernels.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from plantdreamer.errors import InputError
from plantdreamer.exports.dataset import SPLITS_FILE
from plantdreamer.exports.instances import (
    MIN_INSTANCE_AREA,
    PlantClasses,
    labelled_frames,
    read_png,
    view_objects,
)
from plantdreamer.exports.listing import PLANTS_DIR, finished_plants
from plantdreamer.exports.splits import SPLITS


class PlantViews(torch.utils.data.Dataset):
    """The labelled views under ``root``: a plant folder (with ``transforms.json``) or a
    dataset folder (``plants/<id>/``), optionally one ``split`` of its ``splits.json``."""

    def __init__(
        self,
        root: str | Path,
        split: str | None = None,
        min_area: int = MIN_INSTANCE_AREA,
        transforms: Callable[[Any, dict[str, Any]], tuple[Any, dict[str, Any]]] | None = None,
    ) -> None:
        self.root, self.min_area, self.transforms = Path(root), min_area, transforms
        folders = _plant_folders(self.root, split)
        self.views: list[tuple[Path, dict]] = []
        self.classes: dict[int, str] = {}
        for folder in folders:
            for value, name in PlantClasses.read(folder).names.items():
                self.classes.setdefault(value, name)
            self.views += [(folder, frame) for frame in labelled_frames(folder)]

    @property
    def num_classes(self) -> int:
        """Classes including background (0): what detection models' ``num_classes`` takes."""
        return max(self.classes, default=0) + 1

    def __len__(self) -> int:
        return len(self.views)

    def __getitem__(self, index: int) -> tuple[Any, dict[str, Any]]:
        folder, frame = self.views[index]
        rgb = read_png(folder / frame["file_path"])[..., :3]
        semantic = read_png(folder / frame["semantic_path"])
        objects = view_objects(semantic, read_png(folder / frame["instance_path"]), self.min_area)
        image = torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1))).float() / 255.0
        h, w = objects.shape
        target: dict[str, Any] = {
            "boxes": torch.from_numpy(objects.boxes).reshape(-1, 4),
            "labels": torch.from_numpy(objects.categories).to(torch.int64),
            "masks": torch.from_numpy(objects.masks.astype(np.uint8)),
            "semantic": torch.from_numpy(semantic.astype(np.int64)),
            "instance_ids": torch.from_numpy(objects.instance_ids).to(torch.int64),
            "area": torch.from_numpy(objects.areas).to(torch.float32),
            "iscrowd": torch.zeros(len(objects.areas), dtype=torch.int64),
            "image_id": index,
        }
        image, target = _as_tv_tensors(image, target, (h, w))
        if self.transforms is not None:
            image, target = self.transforms(image, target)
        return image, target

    def describe(self, index: int) -> str:
        """Which file an item comes from."""
        folder, frame = self.views[index]
        return str(folder / frame["file_path"])


def collate(batch: list[tuple[Any, dict[str, Any]]]) -> tuple[tuple, tuple]:
    """Images and targets as tuples (detection models take lists of differently sized items)."""
    images, targets = zip(*batch, strict=True)
    return images, targets


def _plant_folders(root: Path, split: str | None) -> list[Path]:
    if (root / "transforms.json").is_file():
        if split is not None:
            raise InputError(f"{root} is one plant folder; a split needs a dataset folder")
        return [root]
    if not (root / PLANTS_DIR).is_dir():
        raise InputError(f"{root} is neither a plant folder nor a dataset folder")
    plants = [p for p in finished_plants(root) if (p.folder / "transforms.json").is_file()]
    if split is not None:
        if split not in SPLITS:
            raise InputError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
        if not (root / SPLITS_FILE).is_file():
            raise InputError(f"{root} has no {SPLITS_FILE}: run `plantdreamer labels` first")
        chosen = set(json.loads((root / SPLITS_FILE).read_text())[split])
        plants = [p for p in plants if p.id in chosen]
    return [p.folder for p in plants]


def _as_tv_tensors(image: torch.Tensor, target: dict[str, Any], size: tuple[int, int]):
    """The torchvision tensor subclasses, which its v2 transforms move together."""
    try:
        from torchvision import tv_tensors
    except ImportError:
        return image, target
    target["boxes"] = tv_tensors.BoundingBoxes(target["boxes"], format="XYXY", canvas_size=size)
    target["masks"] = tv_tensors.Mask(target["masks"])
    target["semantic"] = tv_tensors.Mask(target["semantic"])
    return tv_tensors.Image(image), target
