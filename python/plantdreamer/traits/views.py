"""Per-view traits: what generate measures while it renders a view (each visible leaf's
occlusion, the camera's metres per pixel at the plant) and what the label files measure on
its maps (visible leaves, the plant's projected area, its pixel height and width).

The map figures are taken from the written PNGs (``map_figures``), so ``labels`` remakes
them with its own ``--min-instance-area``; the rendered ones are kept in traits.json's
``views`` (``ViewRecorder``) and read back by the label files (``view_fields``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from plantdreamer.cameras import Camera
from plantdreamer.traits.points import leaf_class_ids, plant_class_ids

if TYPE_CHECKING:
    from plantdreamer.traits.occlusion import LeafOcclusion


class ViewObjectsLike(Protocol):
    """What ``view_fields`` reads of a view's objects (``exports.instances.ViewObjects``:
    exports imports traits, not the reverse): each object's instance id (-1: a class
    piece), its category (class value) and its area in pixels."""

    @property
    def instance_ids(self) -> np.ndarray: ...
    @property
    def categories(self) -> np.ndarray: ...
    @property
    def areas(self) -> np.ndarray: ...


class ViewRecorder:
    """Collects each view's rendered figures while generate renders its views. A view's
    leaf occlusion is measured as the view is added, on the rasterizer's own pool: beside
    the run, on a thread of its own, it cost the 2-core machine more than it hid
    (BENCHMARKS.md, "Trait files")."""

    def __init__(self, occlusion: LeafOcclusion | None, centre: np.ndarray | None, scale: float):
        """``centre``: the plant's centre in the scene frame (None: no plant Gaussians);
        ``scale``: scene units per input unit."""
        self.occlusion, self.centre, self.scale = occlusion, centre, scale
        self.views: list[dict[str, Any]] = []

    def add(self, name: str, camera: Camera, instance_map: np.ndarray | None, meta: dict) -> None:
        """One view: ``instance_map``, its instance ids per pixel (-1: none); ``meta``, its
        render's (the native pass, whose projection the occlusion reuses)."""
        record: dict[str, Any] = {
            "file_path": f"renders/{name}.png",
            "metres_per_pixel": metres_per_pixel(camera, self.centre, self.scale),
        }
        if self.occlusion is not None and instance_map is not None:
            leaves = self.occlusion.view(instance_map, meta["state"])
            record["leaves"] = {str(i): v for i, v in sorted(leaves.items())}
        self.views.append(record)


def metres_per_pixel(camera: Camera, centre: np.ndarray | None, scale: float) -> float | None:
    """The size of one pixel (input units: metres for L-System plants) on the plane
    facing the camera through the plant's centre: its depth along the optical axis over
    the focal length (the mean of fx and fy) in pixels."""
    if centre is None:
        return None
    depth = float((camera.viewmat[:3, :3] @ centre + camera.viewmat[:3, 3])[2])
    if depth <= 0:
        return None
    focal = (float(camera.K[0, 0]) + float(camera.K[1, 1])) / 2.0
    return depth / focal / scale


def map_figures(
    semantic: np.ndarray,
    instance: np.ndarray,
    plant_values: np.ndarray,
    leaf_values: np.ndarray | None,
    min_area: int,
) -> dict[str, int]:
    """A view's figures from its class map (pixel values) and instance map (0: none):
    ``leaf_count``, the leaf instances of at least ``min_area`` pixels (an instance's class
    is the one most of its pixels have, ties to the smaller value; ``leaf_values`` None:
    every instance is a leaf), and the plant's (``plant_values``' pixels) projected area
    and the height and width of the box around it, in pixels."""
    ids = instance.reshape(-1).astype(np.int64)
    fg = np.flatnonzero(ids)
    values, inverse = np.unique(ids[fg], return_inverse=True)
    counts = np.bincount(
        inverse * 256 + semantic.reshape(-1)[fg].astype(np.int64), minlength=len(values) * 256
    ).reshape(len(values), 256)
    counts[counts[:, 1:].any(axis=1), 0] = 0  # unlabelled pixels name a class only alone
    classes = np.argmax(counts, axis=1)
    leaf = np.ones(len(values), bool) if leaf_values is None else np.isin(classes, leaf_values)
    return {
        "leaf_count": int((leaf & (counts.sum(axis=1) >= min_area)).sum()),
        **plant_pixels(semantic, plant_values),
    }


def plant_pixels(semantic: np.ndarray, plant_values: np.ndarray) -> dict[str, int]:
    """The plant's projected area (pixels of ``plant_values`` in the class map) and the
    height and width of the box around it, in pixels."""
    table = np.zeros(256, dtype=bool)
    table[np.asarray(plant_values, dtype=np.int64)] = True
    plant = table[semantic]
    rows, cols = np.flatnonzero(plant.any(axis=1)), np.flatnonzero(plant.any(axis=0))
    return {
        "plant_area_px": int(np.count_nonzero(plant)),
        "plant_height_px": int(rows[-1] - rows[0] + 1) if len(rows) else 0,
        "plant_width_px": int(cols[-1] - cols[0] + 1) if len(cols) else 0,
    }


def view_fields(
    semantic: np.ndarray,
    objects: ViewObjectsLike,
    names: Mapping[int, str],
    min_area: int,
    recorded: Mapping[str, Any] | None,
) -> dict[str, Any]:
    """A view's image-level figures (COCO's image fields, a row of counts.csv), with the
    plant and leaf classes named by ``names`` (pixel value -> class name): ``leaf_count``,
    its instance objects (``objects``: all of the view's, ``exports.instances``) of a leaf
    class and at least ``min_area`` pixels (as ``map_figures`` counts them), the plant's
    pixels (``plant_pixels``) and the recorded ``metres_per_pixel`` (None where generate
    recorded none)."""
    values = np.array(sorted(names), dtype=np.int64)
    leaf_values = leaf_class_ids(values, names)
    leaf = objects.instance_ids >= 0
    if leaf_values is not None:
        leaf &= np.isin(objects.categories, leaf_values)
    figures: dict[str, Any] = {
        "leaf_count": int((leaf & (objects.areas >= min_area)).sum()),
        **plant_pixels(semantic, plant_class_ids(values, names)),
    }
    figures["metres_per_pixel"] = None if recorded is None else recorded.get("metres_per_pixel")
    return figures


def visible_fractions(recorded: Mapping[str, Any] | None) -> dict[int, float]:
    """A view's recorded leaves as ``{instance id: visible fraction}``."""
    if not recorded:
        return {}
    return {
        int(i): (visible / alone if alone else 0.0)
        for i, (alone, visible) in recorded.get("leaves", {}).items()
    }
