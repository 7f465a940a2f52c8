"""The record of ``traits.json``, assembled from its parts (docs/traits.md lists every
field; ``files`` writes it).

- ``plant`` and ``leaves``: from the L-System's mesh and skeleton (``traits.plant``), or a
  scan's labelled points (``traits.points``); ``source`` says which, and each record's
  ``sources`` which part of it each figure comes from;
- ``gaussians``: the same figures on the trained Gaussians, by class and leaf instance;
- ``views``: what generate measured while rendering each view (``traits.views``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from plantdreamer.traits.files import FORMAT
from plantdreamer.traits.occlusion import LeafOcclusion
from plantdreamer.traits.points import (
    gaussian_traits,
    leaf_class_ids,
    plant_class_ids,
    scan_traits,
)
from plantdreamer.traits.views import ViewRecorder

LSYSTEM_FRAME = "metres, z up, the soil surface at z = 0, the pot centred on x = y = 0"
SCAN_FRAME = "the scan's own frame and units (plant.ply's), z taken as up"
SOIL_HEIGHT = 0.0  # the L-System's soil surface


def lsystem_traits(
    species: str, seed: int, growth: float, since: float | None = None
) -> dict[str, Any]:
    """The ``plant`` and ``leaves`` of an L-System plant, grown again from its species,
    seed and stage (the mesh ``generate`` sampled, to the byte)."""
    from plantdreamer.lsystem import grow
    from plantdreamer.traits.plant import LEAF_SOURCES, plant_traits

    record = plant_traits(grow(species, seed, growth), since)
    return {
        "source": "mesh and skeleton",
        "frame": LSYSTEM_FRAME,
        "units": {"length": "m", "area": "m^2", "angle": "degrees"},
        "plant": {**record["plant"], "seed": seed},
        "leaves": record["leaves"],
        "leaf_sources": LEAF_SOURCES,
    }


def captured_traits(
    positions: np.ndarray, labels: np.ndarray | None, names: Mapping[int, str] | None
) -> dict[str, Any]:
    """The ``plant`` and ``leaves`` of a scan from its labelled points."""
    record = scan_traits(positions, labels, names)
    return {
        "source": "labelled points",
        "frame": SCAN_FRAME,
        "units": {"length": "input units", "area": "input units^2", "angle": "degrees"},
        **record,
        "leaf_sources": {"count": "points", "centroid": "points", "extent": "points"},
    }


def assemble(
    plant: dict[str, Any],
    means: np.ndarray,
    labels: np.ndarray | None,
    names: Mapping[int, str] | None,
    views: list[dict[str, Any]],
) -> dict[str, Any]:
    """The whole record: ``plant`` (``lsystem_traits`` or ``captured_traits``), the
    trained Gaussians' figures (``means`` in the input frame, float64) and the views."""
    ground = SOIL_HEIGHT if plant["source"] == "mesh and skeleton" else None
    return {
        "format": FORMAT,
        **plant,
        "gaussians": gaussian_traits(means, labels, names, ground),
        "views": views,
    }


def run_traits(
    species: str | None,
    seed: int,
    growth: float,
    since: float | None,
    start: tuple[np.ndarray, np.ndarray | None],
    final: tuple[np.ndarray, np.ndarray | None],
    names: Mapping[int, str] | None,
    views: ViewRecorder,
) -> dict[str, Any]:
    """The record of a run: an L-System plant's (``species`` grown again from ``seed`` to
    ``growth``) or a scan's (``species`` None: ``start``, the labelled points the run
    started from), the trained Gaussians' (``final``: centres and labels) and the views.
    Positions in the input frame (float64)."""
    if species is not None:
        plant = lsystem_traits(species, seed, growth, since)
    else:
        plant = captured_traits(start[0], start[1], names)
    return assemble(plant, final[0], final[1], names, views.views)


def view_recorder(
    means: np.ndarray,
    labels: np.ndarray | None,
    names: Mapping[int, str] | None,
    scale: float,
    occlusion: bool = True,
) -> ViewRecorder:
    """A recorder of the views of Gaussians (``means`` [N, 3] in the scene frame, ``scale``
    scene units per input unit; the renders the views' ``meta`` come from) with their
    ``labels``; ``occlusion``: measure each visible leaf's (``traits.occlusion``)."""
    centre = None
    if len(means):
        keep = np.ones(len(means), dtype=bool)
        if labels is not None:
            keep = np.isin(labels[:, 0], plant_class_ids(np.unique(labels[:, 0]), names))
        if keep.any():
            centre = np.asarray(means)[keep].astype(np.float64).mean(axis=0)
    leaves = None
    if labels is not None and occlusion:
        leaf_ids = leaf_class_ids(np.unique(labels[:, 0]), names)
        leaf = np.ones(len(labels), bool) if leaf_ids is None else np.isin(labels[:, 0], leaf_ids)
        leaves = LeafOcclusion(labels[:, 1], leaf)
    return ViewRecorder(leaves, centre, scale)
