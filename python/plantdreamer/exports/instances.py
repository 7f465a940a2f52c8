"""The objects of one view, read from its ground-truth PNGs: what COCO, YOLO and the torch
Dataset all start from.

An object is an instance id of ``instances/view_XXX.png`` (value = id + 1, 0 = none). Its
category is the class pixel value (``labels/view_XXX.png``) most of its pixels have (ties: the
smaller value; unlabelled pixels, 0, only when nothing else is there). An object of fewer than
``min_area`` pixels is left out and counted: a leaf seen edge-on is a sliver of 1-4 pixels
that detection losses cannot use (a 1-pixel-wide mask has a zero-width box in
``torchvision.ops.masks_to_boxes``). Boxes here are pixel-edge boxes, [x0, y0, x1 + 1,
y1 + 1] for a mask spanning columns x0..x1, as COCO measures them: never zero-sized.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantdreamer.errors import InputError

# Default smallest object, in pixels, written to the label files (COCO "small" starts at 32^2:
# this keeps small leaves and drops slivers).
MIN_INSTANCE_AREA = 16


@dataclass(frozen=True)
class ViewObjects:
    """The objects of one view, sorted by instance id; ``masks`` is bool [K, H, W]."""

    instance_ids: np.ndarray  # int64 [K]: the ids of the PLY's ``instance`` property
    categories: np.ndarray  # int64 [K]: class pixel values (1..255)
    masks: np.ndarray
    areas: np.ndarray  # int64 [K]
    boxes: np.ndarray  # float32 [K, 4], x0 y0 x1 y1 (pixel edges)
    dropped: int  # objects under the area limit
    shape: tuple[int, int]  # the view's height and width


@dataclass(frozen=True)
class PlantClasses:
    """A labelled plant folder's classes: pixel value -> name (from transforms.json)."""

    names: dict[int, str]

    @classmethod
    def read(cls, plant_dir: Path) -> PlantClasses:
        meta = read_transforms(plant_dir)
        classes = meta.get("semantic_classes")
        if not classes:
            raise InputError(
                f"{plant_dir} has no labelled views (transforms.json lists no classes)"
            )
        return cls({int(c["value"]): str(c["name"]) for c in classes})


def read_transforms(plant_dir: Path) -> dict:
    path = Path(plant_dir) / "transforms.json"
    if not path.is_file():
        raise InputError(f"{plant_dir} is not a plant folder: it has no transforms.json")
    try:
        meta = json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path} is not valid JSON (cut short or damaged: {exc})") from None
    if not isinstance(meta, dict):
        raise InputError(f"{path} is not a transforms.json (not a JSON object)")
    return meta


def labelled_frames(plant_dir: Path) -> list[dict]:
    """The frames of transforms.json that have class and instance maps."""
    frames = [f for f in read_transforms(plant_dir)["frames"] if "instance_path" in f]
    if not frames:
        raise InputError(f"{plant_dir} has no labelled views (no instance masks)")
    return frames


def read_png(path: Path) -> np.ndarray:
    import imageio.v3 as iio

    return np.asarray(iio.imread(path))


def view_objects(
    semantic: np.ndarray, instance: np.ndarray, min_area: int = MIN_INSTANCE_AREA
) -> ViewObjects:
    """The objects of a view from its class map (uint8) and instance map (uint16, id + 1)."""
    if semantic.shape != instance.shape or semantic.ndim != 2:
        raise InputError(
            f"class and instance maps differ in shape: {semantic.shape} vs {instance.shape}"
        )
    if min_area < 1:
        raise InputError(f"the minimum instance area must be at least 1 pixel, got {min_area}")
    h, w = instance.shape
    flat = instance.reshape(-1).astype(np.int64)
    fg = np.flatnonzero(flat)
    values, areas = np.unique(flat[fg], return_counts=True)
    keep = areas >= min_area
    values, areas = values[keep], areas[keep]
    masks = np.zeros((len(values), h, w), dtype=bool)
    index = np.searchsorted(values, flat[fg])
    inside = index < len(values)
    inside[inside] = values[index[inside]] == flat[fg][inside]
    masks.reshape(len(values), h * w)[index[inside], fg[inside]] = True
    categories = np.array(
        [
            _majority(semantic.reshape(-1)[fg[inside][index[inside] == k]])
            for k in range(len(values))
        ],
        dtype=np.int64,
    )
    return ViewObjects(
        instance_ids=values - 1,
        categories=categories,
        masks=masks,
        areas=areas.astype(np.int64),
        boxes=_boxes(masks),
        dropped=int((~keep).sum()),
        shape=(h, w),
    )


def read_view_objects(
    plant_dir: Path, frame: dict, min_area: int = MIN_INSTANCE_AREA
) -> ViewObjects:
    """``view_objects`` of one frame of a plant folder's transforms.json."""
    semantic = read_png(Path(plant_dir) / frame["semantic_path"])
    instance = read_png(Path(plant_dir) / frame["instance_path"])
    return view_objects(semantic, instance, min_area)


def _majority(values: np.ndarray) -> int:
    counts = np.bincount(values.astype(np.int64), minlength=256)
    if counts[1:].any():
        counts[0] = 0  # unlabelled pixels name a class only when nothing else does
    return int(np.argmax(counts))  # first maximum: ties go to the smaller value


def _boxes(masks: np.ndarray) -> np.ndarray:
    boxes = np.zeros((len(masks), 4), dtype=np.float32)
    for k, mask in enumerate(masks):
        ys, xs = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        boxes[k] = (xs[0], ys[0], xs[-1] + 1, ys[-1] + 1)
    return boxes
