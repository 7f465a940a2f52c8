"""``PlantViews``: the labelled views of a plant folder or a dataset folder as a torch
``Dataset`` whose items torchvision's detection and segmentation models take as they are.

Each item is ``(image, target)``:

- ``image``: float32 [3, H, W] in [0, 1] (a ``tv_tensors.Image`` when torchvision is there);
- ``target["boxes"]``: float32 [K, 4] x0 y0 x1 y1, pixel edges, never zero-sized
  (``tv_tensors.BoundingBoxes``, XYXY);
- ``target["labels"]``: int64 [K], the category ids of the COCO files (1..; 0 is
  background, so ``num_classes`` = largest id + 1 for Mask R-CNN);
- ``target["masks"]``: uint8 [K, H, W] (``tv_tensors.Mask``);
- ``target["semantic"]``: int64 [H, W] class map in category ids (0 background), ready for a
  cross-entropy;
- ``target["ignore"]``: uint8 [H, W], the pixels of the ignore regions (objects under
  ``min_area``: COCO's ``iscrowd`` 1 annotations), which the K objects leave out;
- ``target["instance_ids"]``, ``target["area"]``, ``target["iscrowd"]`` (all 0), and
  ``target["image_id"]``: the id of the view's image in ``coco/<split>.json`` (and a plant
  folder's ``coco.json``), so predictions score against those files as they are;
- the view's traits (docs/traits.md): ``target["visible_fraction"]``, float32 [K], each
  leaf's share of itself the view shows (NaN for other objects, or where generate
  measured none), and the image's ``leaf_count`` (visible leaves of at least ``min_area``
  pixels), ``plant_area_px``, ``plant_height_px``, ``plant_width_px`` (taken again from
  ``semantic`` after the transforms) and ``metres_per_pixel`` (the written view's; NaN
  where unknown), as COCO's image records and ``counts.csv`` give them;
- ``target["traits"]``: the plant's traits (traits.json's ``plant``: species, seed, stage,
  leaf count, leaf area, height, canopy width and hull area, stem count; empty without a
  traits.json), for trait regression from the views.

The area limit and stuff classes are those the folder's label files record (``coco.json``,
``coco/<split>.json``: what ``labels --min-instance-area --stuff`` made), so the targets are
the objects, category ids and ``num_classes`` of the COCO and YOLO files; ``min_area`` or
``stuff`` given otherwise is refused (remake the label files instead). A folder without
label files takes them as given (defaults: ``labels``' defaults). A dataset folder whose
label files a stopped export left a mix of two (``export.incomplete``) is refused.

``semantic`` and ``ignore`` are ``data.pixel_map.PixelMap`` tensors: the geometric v2
transforms move them as they move a mask, and ``SanitizeBoundingBoxes`` leaves them whole.

``target_keys`` picks the keys, as torchvision's ``wrap_dataset_for_transforms_v2`` takes
them: ``None`` or ``"all"`` (every key above), or the names wanted, such as the detection
references' ``DETECTION_KEYS`` (``boxes``, ``labels``, ``image_id``, ``masks``).

A v2 transform that drops boxes (``SanitizeBoundingBoxes``) drops the boxes, the masks and
what its ``labels_getter`` names (by default ``labels``): on ``DETECTION_KEYS`` the default
transform is all it takes; with every key, pass ``labels_getter=object_keys`` and
``labels``, ``area``, ``iscrowd``, ``instance_ids`` and ``visible_fraction`` follow the boxes.
``area`` and the plant's pixel figures are taken again from the masks and ``semantic`` after
the transforms (a resize or crop changes them), and an item whose per-object keys no longer
line up with its boxes is refused in one line naming both fixes. The 16-bit instance PNGs
never reach the user: torch has few uint16 kernels.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from plantdreamer.errors import InputError
from plantdreamer.exports.dataset import SPLITS_FILE, dataset_views, labelled_plants
from plantdreamer.exports.dataset_files import check_incomplete
from plantdreamer.exports.figures import read_view_traits
from plantdreamer.exports.instances import MIN_INSTANCE_AREA, read_png, read_transforms
from plantdreamer.exports.listing import PLANTS_DIR, finished_plants, finished_scenes
from plantdreamer.exports.plant import COCO_FILE, PLANT, plant_classes, plant_views
from plantdreamer.exports.splits import SPLITS
from plantdreamer.traits import read_traits, recorded_views
from plantdreamer.traits.counts import plant_row
from plantdreamer.traits.points import plant_class_ids

OBJECT_KEYS = ("labels", "area", "iscrowd", "instance_ids", "visible_fraction")  # per box
# Every key of a target, in the order an item holds them: the labels, then the traits.
TARGET_KEYS = (
    "boxes", "labels", "masks", "semantic", "ignore", "instance_ids", "area", "iscrowd",
    "visible_fraction", "image_id", "leaf_count", "plant_area_px", "plant_height_px",
    "plant_width_px", "metres_per_pixel", "traits",
)  # fmt: skip
# The keys torchvision's detection references ask of a dataset (Mask R-CNN's: with masks).
DETECTION_KEYS = ("boxes", "labels", "image_id", "masks")


def object_keys(inputs: Any) -> tuple[torch.Tensor, ...]:
    """``SanitizeBoundingBoxes``' ``labels_getter`` for these targets: the per-object
    tensors it must filter with the boxes."""
    target = inputs[1] if isinstance(inputs, tuple | list) else inputs
    return tuple(target[key] for key in OBJECT_KEYS if key in target)


class PlantViews(torch.utils.data.Dataset):
    """The labelled views under ``root``: a plant folder (with ``transforms.json``) or a
    dataset folder (``plants/<id>/``), optionally one ``split`` of its ``splits.json``;
    ``min_area`` and ``stuff`` (class names that are no objects): those of the label files,
    which these may only repeat; ``target_keys``: the keys of each target (the module's
    docstring)."""

    def __init__(
        self,
        root: str | Path,
        split: str | None = None,
        min_area: int | None = None,
        transforms: Callable[[Any, dict[str, Any]], tuple[Any, dict[str, Any]]] | None = None,
        stuff: tuple[str, ...] | None = None,
        target_keys: str | Iterable[str] | None = None,
    ) -> None:
        self.root, self.transforms = Path(root), transforms
        self.target_keys = _target_keys(target_keys)
        self.min_area, stuff = _label_options(self.root, split, min_area, stuff)
        # (image id, folder, frame, class lookup table) per view
        self.views: list[tuple[int, Path, dict, np.ndarray]] = []
        if (self.root / "transforms.json").is_file():
            if split is not None:
                raise InputError(f"{root} is one plant folder; a split needs a dataset folder")
            classes = plant_classes(self.root)
            lut = classes.luts[PLANT]
            self.views = [(v.image_id, self.root, v.frame, lut) for v in plant_views(self.root)]
        else:
            plants, classes = labelled_plants(_dataset_plants(self.root))
            chosen = _split_plants(self.root, split)
            self.views = [
                (v.image_id, v.plant.folder, v.frame, classes.luts[v.plant.id])
                for v in dataset_views(plants)
                if chosen is None or v.plant.id in chosen
            ]
        self.stuff_ids = classes.stuff_ids(tuple(stuff))
        self.classes: dict[int, str] = classes.things(tuple(stuff))
        self.names = classes.names  # every class, stuff too: the traits' plant and leaves
        self.plant_values = plant_class_ids(np.array(sorted(self.names)), self.names)
        self._traits: dict[Path, dict[str, Any] | None] = {}  # traits.json by folder

    @property
    def num_classes(self) -> int:
        """Classes including background (0): what detection models' ``num_classes`` takes."""
        return max(self.classes, default=0) + 1

    def __len__(self) -> int:
        return len(self.views)

    def __getitem__(self, index: int) -> tuple[Any, dict[str, Any]]:
        image_id, folder, frame, lut = self.views[index]
        rgb = read_png(folder / frame["file_path"])[..., :3]
        if folder not in self._traits:
            self._traits[folder] = read_traits(folder)
        record = self._traits[folder]
        seen = read_view_traits(folder, frame, self.min_area, lut, self.names,
                                self.stuff_ids, recorded_views(record))  # fmt: skip
        semantic, objects = seen.semantic, seen.objects
        things = objects.things()
        fraction = [o.get("visible_fraction", np.nan) for o, t in
                    zip(seen.per_object, ~objects.iscrowd, strict=True) if t]  # fmt: skip
        image = torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1))).float() / 255.0
        h, w = objects.shape
        target: dict[str, Any] = {
            "boxes": torch.from_numpy(things.boxes).reshape(-1, 4),
            "labels": torch.from_numpy(things.categories).to(torch.int64),
            "masks": torch.from_numpy(things.masks.astype(np.uint8)),
            "semantic": torch.from_numpy(semantic.astype(np.int64)),
            "ignore": torch.from_numpy(objects.ignore_mask().astype(np.uint8)),
            "instance_ids": torch.from_numpy(things.instance_ids).to(torch.int64),
            "area": torch.from_numpy(things.areas).to(torch.float32),
            "iscrowd": torch.zeros(len(things.areas), dtype=torch.int64),
            "visible_fraction": torch.tensor(fraction, dtype=torch.float32),
            "image_id": image_id,
            **seen.fields,
            "traits": plant_row(record) if record is not None else {},
        }
        if target["metres_per_pixel"] is None:
            target["metres_per_pixel"] = float("nan")
        target = {key: target[key] for key in self.target_keys}
        image, target = _as_tv_tensors(image, target, (h, w))
        if self.transforms is not None:
            image, target = self.transforms(image, target)
            _follow_boxes(target, self.describe(index), self.plant_values)
        return image, target

    def describe(self, index: int) -> str:
        """Which file an item comes from."""
        _, folder, frame, _ = self.views[index]
        return str(folder / frame["file_path"])


def collate(batch: list[tuple[Any, dict[str, Any]]]) -> tuple[tuple, tuple]:
    """Images and targets as tuples (detection models take lists of differently sized items)."""
    images, targets = zip(*batch, strict=True)
    return images, targets


def _target_keys(given: str | Iterable[str] | None) -> tuple[str, ...]:
    """The keys of each target: every one (None, ``"all"``) or those given, in the order
    of ``TARGET_KEYS``; an unknown name is refused, naming the known ones."""
    if given is None or given == "all":
        return TARGET_KEYS
    if isinstance(given, str):
        raise InputError(
            f"target_keys must be 'all' or a list of key names, got {given!r} "
            f"(one key: target_keys=[{given!r}])"
        )
    names = set(given)
    unknown = sorted(n for n in names if n not in TARGET_KEYS)
    if unknown:
        raise InputError(
            f"target_keys has no {', '.join(map(repr, unknown))}: the keys are "
            f"{', '.join(TARGET_KEYS)}, or 'all'"
        )
    if "boxes" not in names and names & set(OBJECT_KEYS):
        raise InputError(
            f"target_keys {', '.join(k for k in TARGET_KEYS if k in names)} need boxes: "
            "their entries are one per box"
        )
    return tuple(k for k in TARGET_KEYS if k in names)


def _follow_boxes(target: dict[str, Any], source: str, plant_values: np.ndarray) -> None:
    """``area`` again from the masks and the plant's pixel figures from ``semantic``;
    every per-object key as long as the boxes."""
    if "masks" in target and "area" in target:
        target["area"] = torch.as_tensor(target["masks"]).flatten(1).sum(1).to(torch.float32)
    if "semantic" in target:
        plant = torch.isin(torch.as_tensor(target["semantic"]), torch.from_numpy(plant_values))
        rows, cols = torch.nonzero(plant.any(1)), torch.nonzero(plant.any(0))
        for key, value in (
            ("plant_area_px", int(plant.sum())),
            ("plant_height_px", int(rows[-1] - rows[0] + 1) if len(rows) else 0),
            ("plant_width_px", int(cols[-1] - cols[0] + 1) if len(cols) else 0),
        ):
            if key in target:
                target[key] = value
    if "boxes" not in target:
        return
    k = len(target["boxes"])
    wrong = [key for key in OBJECT_KEYS if key in target and len(target[key]) != k]
    if wrong:
        raise InputError(
            f"{source}: after the transforms {', '.join(wrong)} no longer have one entry per "
            f"box ({k}); give SanitizeBoundingBoxes labels_getter=plantdreamer.data.object_keys, "
            "or PlantViews target_keys=plantdreamer.data.DETECTION_KEYS"
        )


def _label_options(
    root: Path, split: str | None, min_area: int | None, stuff: tuple[str, ...] | None
) -> tuple[int, tuple[str, ...]]:
    """The area limit and stuff classes of the label files under ``root`` (the split's COCO
    file, else any split's, else a plant's coco.json); given ones must agree with them."""
    names = [f"coco/{split}.json"] if split else [f"coco/{s}.json" for s in SPLITS]
    files = [p for p in (root / n for n in (*names, COCO_FILE)) if p.is_file()]
    if not files:
        return (MIN_INSTANCE_AREA if min_area is None else min_area), tuple(stuff or ())
    area, things = _recorded_options(files[0])
    given = {"min_area": (min_area, area), "stuff": (stuff and tuple(stuff), things)}
    other = [f"{k}={g!r}" for k, (g, r) in given.items() if g is not None and g != r]
    if other:
        raise InputError(
            f"{files[0]} was made with --min-instance-area {area} and --stuff "
            f"{','.join(things) or '(none)'}; PlantViews got {', '.join(other)}: leave them "
            "out, or remake the label files with `plantdreamer labels`"
        )
    return area, things


def _recorded_options(path: Path) -> tuple[int, tuple[str, ...]]:
    try:
        info = json.loads(path.read_bytes().decode("utf-8"))["info"]
        return int(info["min_instance_area"]), tuple(str(n) for n in info.get("stuff_classes", []))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(
            f"{path} does not record its label options (damaged or too old: {exc}); remake it "
            "with `plantdreamer labels`"
        ) from None


def _dataset_plants(root: Path):
    if not (root / PLANTS_DIR).is_dir():
        raise InputError(f"{root} is neither a plant folder nor a dataset folder")
    check_incomplete(root)  # a stopped swap's mix of two exports
    entries = finished_plants(root) + finished_scenes(root)  # scenes' views after the plants'
    plants = [p for p in entries if (p.folder / "transforms.json").is_file()]
    for p in plants:
        read_transforms(p.folder)  # a damaged one is refused, not left out
    return plants


def _split_plants(root: Path, split: str | None) -> set[str] | None:
    if split is None:
        return None
    if split not in SPLITS:
        raise InputError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
    if not (root / SPLITS_FILE).is_file():
        raise InputError(f"{root} has no {SPLITS_FILE}: run `plantdreamer labels` first")
    recorded = json.loads((root / SPLITS_FILE).read_text())
    return set(recorded[split]) | set(recorded.get("scenes", {}).get(split, []))


def _as_tv_tensors(image: torch.Tensor, target: dict[str, Any], size: tuple[int, int]):
    """The torchvision tensor subclasses, which its v2 transforms move together."""
    try:
        from torchvision import tv_tensors
    except ImportError:
        return image, target
    from plantdreamer.data.pixel_map import PixelMap

    wrappers: dict[str, Callable[[Any], Any]] = {
        "boxes": lambda t: tv_tensors.BoundingBoxes(t, format="XYXY", canvas_size=size),
        "masks": tv_tensors.Mask,
        "semantic": PixelMap,
        "ignore": PixelMap,
    }
    for key, wrap in wrappers.items():
        if key in target:
            target[key] = wrap(target[key])
    return tv_tensors.Image(image), target
