"""The objects of one view, read from its ground-truth PNGs: what COCO, YOLO and the torch
Dataset all start from.

Every class is annotated, so no format declares a class it never holds:

- a class that instances have in the view (the L-System's leaves) has one object
  per instance id of ``instances/view_XXX.png`` (value = id + 1, 0 = none), whatever number
  of pieces occlusion cuts it into; its category is the class most of its pixels have
  (ties: the smaller value). An instance none of whose pixels has a class names no category:
  it is left out and counted (``unclassed``);
- a class without instance ids (stems, pot, soil) has one object per 8-connected piece of
  its pixels: a stem seen between two leaves is two objects, a pot seen whole is one.

An object of fewer than ``min_area`` pixels is an ignore region (``iscrowd``): a leaf seen
edge-on is a sliver of 1-4 pixels that detection losses cannot use, but its pixels are not
background either, so COCO keeps it as a crowd annotation (which COCOeval, torchvision's
references and Detectron2 neither train on nor count as a miss), and YOLO and the torch
Dataset leave it out. Boxes here are pixel-edge boxes, [x0, y0, x1 + 1, y1 + 1] for a mask
spanning columns x0..x1, as COCO measures them: never zero-sized.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.exports.pieces import label_pieces

# Default smallest object, in pixels, trained on (COCO "small" starts at 32^2: this keeps
# small leaves and makes slivers ignore regions).
MIN_INSTANCE_AREA = 16


@dataclass(frozen=True)
class ViewObjects:
    """The objects of one view (instance objects by id, then class pieces by class and raster
    order); ``masks`` is bool [K, H, W]; ``iscrowd`` marks the ignore regions."""

    instance_ids: np.ndarray  # int64 [K]: the PLY's ``instance`` ids, -1 for a class piece
    categories: np.ndarray  # int64 [K]: class pixel values (1..255)
    masks: np.ndarray
    areas: np.ndarray  # int64 [K]
    boxes: np.ndarray  # float32 [K, 4], x0 y0 x1 y1 (pixel edges)
    iscrowd: np.ndarray  # bool [K]: under the area limit, an ignore region
    unclassed: int  # instance ids with no class pixel, left out
    shape: tuple[int, int]  # the view's height and width

    @property
    def objects(self) -> int:
        """Objects trained on (not ignore regions)."""
        return int((~self.iscrowd).sum())

    @property
    def ignored(self) -> int:
        return int(self.iscrowd.sum())

    def things(self) -> ViewObjects:
        """The objects that are not ignore regions."""
        return self.select(~self.iscrowd)

    def without(self, categories: tuple[int, ...]) -> ViewObjects:
        """The objects of other categories (``categories``: the stuff classes)."""
        return self.select(~np.isin(self.categories, categories)) if categories else self

    def select(self, keep: np.ndarray) -> ViewObjects:
        """The objects where ``keep`` (bool [K]) is true."""
        return replace(
            self,
            instance_ids=self.instance_ids[keep],
            categories=self.categories[keep],
            masks=self.masks[keep],
            areas=self.areas[keep],
            boxes=self.boxes[keep],
            iscrowd=self.iscrowd[keep],
        )

    def ignore_mask(self) -> np.ndarray:
        """bool [H, W]: the pixels of the ignore regions."""
        return self.masks[self.iscrowd].any(axis=0) if self.ignored else np.zeros(self.shape, bool)


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
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path} is not valid JSON (cut short or damaged: {exc})") from None
    if not isinstance(meta, dict):
        raise InputError(f"{path} is not a transforms.json (not a JSON object)")
    if not isinstance(meta.get("frames"), list):
        raise InputError(f"{path} has no list of frames")
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


def image_size(path: Path) -> tuple[int, int]:
    """A PNG's height and width, from its header."""
    from PIL import Image

    try:
        with Image.open(path) as image:
            return image.height, image.width
    except OSError as e:
        raise InputError(f"{path} cannot be read as an image ({e})") from None


def read_label_maps(plant_dir: Path, frame: dict) -> tuple[np.ndarray, np.ndarray]:
    """A frame's class and instance maps, refused in one line when their size is not its
    render's (a label file that is not the render's would label other pixels)."""
    plant_dir = Path(plant_dir)
    semantic = read_png(plant_dir / frame["semantic_path"])
    instance = read_png(plant_dir / frame["instance_path"])
    render = plant_dir / frame["file_path"]
    size = image_size(render)
    for path, array in ((frame["semantic_path"], semantic), (frame["instance_path"], instance)):
        if array.shape[:2] != size:
            h, w = array.shape[:2]
            raise InputError(
                f"{plant_dir / path} is {w}x{h} px but its render {render} is "
                f"{size[1]}x{size[0]} px: remake the labels (plantdreamer render --labels)"
            )
    return semantic, instance


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
    classes = semantic.reshape(-1).astype(np.int64)
    ids = instance.reshape(-1).astype(np.int64)
    fg = np.flatnonzero(ids)
    values, inverse = np.unique(ids[fg], return_inverse=True)
    counts = np.bincount(inverse * 256 + classes[fg], minlength=len(values) * 256)
    counts = counts.reshape(len(values), 256)
    counts[counts[:, 1:].any(axis=1), 0] = 0  # unlabelled pixels name a class only alone
    categories = np.argmax(counts, axis=1)  # first maximum: ties go to the smaller value
    classed = categories > 0
    # Object k's pixels: label k + 1 in one map of the view.
    objects = np.zeros(h * w, dtype=np.int32)
    slot = np.cumsum(classed) * classed  # 1.. for classed instances, 0 for the others
    objects[fg] = slot[inverse]
    cats, ids_out = list(categories[classed]), list(values[classed] - 1)
    instanced = np.unique(categories[classed])
    loose = (ids == 0) & (classes > 0) & ~np.isin(classes, instanced)
    for value in np.unique(classes[loose]):
        pieces, n = label_pieces((loose & (classes == value)).reshape(h, w))
        piece = pieces.reshape(-1)
        objects[piece > 0] = piece[piece > 0] + len(cats)
        cats += [value] * n
        ids_out += [-1] * n
    k = len(cats)
    areas = np.bincount(objects, minlength=k + 1)[1:]
    masks = np.zeros((k, h * w), dtype=bool)
    pixels = np.flatnonzero(objects)
    masks[objects[pixels] - 1, pixels] = True
    masks = masks.reshape(k, h, w)
    return ViewObjects(
        instance_ids=np.asarray(ids_out, dtype=np.int64),
        categories=np.asarray(cats, dtype=np.int64),
        masks=masks,
        areas=areas.astype(np.int64),
        boxes=_boxes(masks),
        iscrowd=areas < min_area,
        unclassed=int((~classed).sum()),
        shape=(h, w),
    )


def _boxes(masks: np.ndarray) -> np.ndarray:
    boxes = np.zeros((len(masks), 4), dtype=np.float32)
    for k, mask in enumerate(masks):
        ys, xs = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        boxes[k] = (xs[0], ys[0], xs[-1] + 1, ys[-1] + 1)
    return boxes
