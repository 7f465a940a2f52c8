"""Traits of labelled points: a scan's (the points a run started from) or the trained
Gaussians' centres, by class and by instance, in the input's frame and units (z up).

Which classes are the plant: every class but those named ``pot`` and ``soil``; which are
leaves: the class named ``leaf``, or, where no class has that name (a scan's own ids),
every instance is a leaf (the leaf count of a scan is its instance count).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from plantdreamer.labels import NO_INSTANCE
from plantdreamer.traits.shapes import canopy, extent

NOT_PLANT = ("pot", "soil")  # class names the plant's size leaves out
LEAF = "leaf"
SCAN_SOURCES = {
    "leaf_count": "points",
    "height": "points",
    "canopy_width": "points",
    "canopy_hull_area": "points",
}


def plant_class_ids(classes: np.ndarray, names: Mapping[int, str] | None) -> np.ndarray:
    """The class ids (of ``classes``) that are the plant."""
    names = names or {}
    return np.array([c for c in classes if names.get(int(c), "") not in NOT_PLANT], dtype=np.int64)


def leaf_class_ids(classes: np.ndarray, names: Mapping[int, str] | None) -> np.ndarray | None:
    """The leaf class ids, or None when no class is named ``leaf`` (every instance is a
    leaf then)."""
    names = names or {}
    leaf = [c for c in classes if names.get(int(c)) == LEAF]
    return np.array(leaf, dtype=np.int64) if leaf else None


def _leaf_points(labels: np.ndarray, names: Mapping[int, str] | None) -> np.ndarray:
    """bool [N]: the points of a leaf instance."""
    has_instance = labels[:, 1] != NO_INSTANCE
    leaf = leaf_class_ids(np.unique(labels[:, 0]), names)
    return has_instance if leaf is None else has_instance & np.isin(labels[:, 0], leaf)


def _plant_points(labels: np.ndarray | None, n: int, names: Mapping[int, str] | None):
    if labels is None:
        return np.ones(n, dtype=bool)
    return np.isin(labels[:, 0], plant_class_ids(np.unique(labels[:, 0]), names))


def group_traits(points: np.ndarray) -> dict[str, Any]:
    """Count, centroid (the points' mean) and extent (axis-aligned size) of some points."""
    p = np.asarray(points, dtype=np.float64)
    return {
        "count": len(p),
        "centroid": p.mean(axis=0).tolist() if len(p) else None,
        "extent": extent(p),
    }


def size_traits(points: np.ndarray, ground: float | None) -> dict[str, float]:
    """Height (the highest point above ``ground``; None: the points' extent along z),
    canopy width and its hull's area seen from above."""
    p = np.asarray(points, dtype=np.float64)
    if len(p) == 0:
        return {"height": 0.0, "canopy_width": 0.0, "canopy_hull_area": 0.0}
    top = float(p[:, 2].max())
    width, hull_area = canopy(p)
    height = top - (float(p[:, 2].min()) if ground is None else ground)
    return {"height": height, "canopy_width": width, "canopy_hull_area": hull_area}


def instance_traits(
    positions: np.ndarray, labels: np.ndarray, names: Mapping[int, str] | None
) -> list[dict[str, Any]]:
    """Per leaf instance (ascending id): its points' count, centroid and extent."""
    leaf = _leaf_points(labels, names)
    ids, inverse = np.unique(labels[leaf, 1], return_inverse=True)
    order = np.argsort(inverse, kind="stable")
    bounds = np.searchsorted(inverse[order], np.arange(len(ids) + 1))
    chosen = np.asarray(positions)[leaf][order]
    return [
        {"instance": int(i), **group_traits(chosen[bounds[k] : bounds[k + 1]])}
        for k, i in enumerate(ids)
    ]


def scan_traits(
    positions: np.ndarray, labels: np.ndarray | None, names: Mapping[int, str] | None
) -> dict[str, Any]:
    """The ``plant`` and ``leaves`` records of a scan from its labelled points: the leaf
    count by instance, height (extent along z) and canopy of the plant's points, each
    leaf's extent and centroid."""
    p = np.asarray(positions, dtype=np.float64)
    plant = _plant_points(labels, len(p), names)
    leaves = [] if labels is None else instance_traits(p, labels, names)
    return {
        "plant": {
            "leaf_count": len(leaves),
            **size_traits(p[plant], ground=None),
            "points": int(plant.sum()),
            "sources": SCAN_SOURCES,
        },
        "leaves": [{**leaf, "sources": "points"} for leaf in leaves],
    }


def gaussian_traits(
    means: np.ndarray,
    labels: np.ndarray | None,
    names: Mapping[int, str] | None,
    ground: float | None,
) -> dict[str, Any]:
    """The same figures on trained Gaussians' centres: the plant's size (``ground``: the
    soil's height, None for a scan: the extent along z), each class's and each leaf
    instance's count, centroid and extent."""
    p = np.asarray(means, dtype=np.float64)
    plant = _plant_points(labels, len(p), names)
    record: dict[str, Any] = {"plant": {**size_traits(p[plant], ground), "count": int(plant.sum())}}
    if labels is not None:
        names = names or {}
        record["classes"] = {
            names.get(int(c), f"class {int(c)}"): group_traits(p[labels[:, 0] == c])
            for c in np.unique(labels[:, 0])
        }
        record["leaves"] = instance_traits(p, labels, names)
    return record
