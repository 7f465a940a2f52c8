"""A labelled view with its traits: its objects (``instances``), its image-level figures
(visible leaves, the plant's size in pixels, metres per pixel: ``traits.views``) and each
leaf object's visible fraction, which COCO, counts.csv and the torch Dataset all carry."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer.exports.instances import ViewObjects, read_label_maps, view_objects
from plantdreamer.traits import read_traits, recorded_views
from plantdreamer.traits.views import view_fields, visible_fractions


@dataclass(frozen=True)
class ViewTraits:
    """A view's objects, its figures (COCO image fields) and per object its extra
    annotation keys (``visible_fraction`` for a leaf whose occlusion generate measured)."""

    objects: ViewObjects
    fields: dict[str, Any]
    per_object: list[dict[str, Any]]
    semantic: np.ndarray  # the class map, in category ids


def plant_records(plant_dir: Path) -> dict[str, dict[str, Any]]:
    """The views generate recorded in a plant folder's traits.json, by render path."""
    return recorded_views(read_traits(plant_dir))


def read_view_traits(
    plant_dir: Path,
    frame: dict,
    min_area: int,
    lut: np.ndarray,
    names: Mapping[int, str],
    stuff: tuple[int, ...],
    recorded: Mapping[str, dict[str, Any]],
) -> ViewTraits:
    """One frame of a plant folder: its objects (class values through ``lut``; ``stuff``
    left out) and traits (``names``: class value -> name, after ``lut``)."""
    semantic, instance = read_label_maps(plant_dir, frame)
    semantic = lut[semantic]
    every = view_objects(semantic, instance, min_area)
    objects = every.without(stuff)
    record = recorded.get(str(frame["file_path"]))
    fields = view_fields(semantic, every, names, min_area, record)
    fractions = visible_fractions(record)
    per_object = [
        {"visible_fraction": fractions[int(i)]} if int(i) in fractions else {}
        for i in objects.instance_ids
    ]
    return ViewTraits(objects, fields, per_object, semantic)
