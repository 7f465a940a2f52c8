"""The classes of a set of plants, keyed by name: one category per class name, whatever
pixel value each plant's class maps give it.

When every plant gives each name the same value (and no value two names: the L-System's
leaf 1, stem 2, pot 3, soil 4 everywhere), the values stay the category ids. Otherwise the
names are numbered 1..K in order of the smallest value any plant gives them (then by name),
and each plant's class map pixels are moved to those ids through a lookup table before any
object is made, so a scan whose class 1 is "soil" beside L-System plants is annotated soil.

Classes named as "stuff" (``--stuff pot,soil``) are no objects: COCO, YOLO and the torch
Dataset's targets do not declare them, and they stay in the class maps (``labels/``, the
torch Dataset's ``semantic``), as COCO's stuff and panoptic sets keep amorphous regions.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from plantdreamer.errors import InputError


@dataclass(frozen=True)
class DatasetClasses:
    """``names``: category id -> name; ``luts[plant]``: uint8 [256], the plant's class map
    value -> category id (0, and a value the plant names no class for, -> 0: unlabelled);
    ``remapped``: the plants whose values were moved."""

    names: dict[int, str]
    luts: dict[str, np.ndarray]
    remapped: tuple[str, ...] = ()

    def stuff_ids(self, stuff: tuple[str, ...]) -> tuple[int, ...]:
        """The ids of the classes named ``stuff`` (``--stuff``), refused in one line when
        a name is not a class."""
        ids = {name: i for i, name in self.names.items()}
        check_stuff(stuff, self.names.values())
        return tuple(sorted(ids[name] for name in stuff))

    def things(self, stuff: tuple[str, ...]) -> dict[int, str]:
        """The classes that are objects: all but the ``stuff``."""
        return {i: n for i, n in self.names.items() if n not in stuff}


def check_stuff(stuff: tuple[str, ...], classes: Iterable[str]) -> None:
    """Refuses in one line a ``--stuff`` name that is no class, and ``--stuff`` naming
    every class (label files without one object or category)."""
    classes = list(dict.fromkeys(classes))
    unknown = [name for name in stuff if name not in classes]
    if unknown:
        raise InputError(
            f"--stuff names no class {', '.join(map(repr, unknown))} "
            f"(the classes: {', '.join(classes)})"
        )
    if classes and set(classes) <= set(stuff):
        raise InputError(
            f"--stuff names every class ({', '.join(classes)}): the label files would hold no "
            "object; leave at least one class out of it"
        )


def dataset_classes(maps: dict[str, dict[int, str]]) -> DatasetClasses:
    """The categories of plants with class maps ``maps[plant] = {value: name}``."""
    value_of: dict[str, set[int]] = {}
    name_of: dict[int, set[str]] = {}
    for names in maps.values():
        for value, name in names.items():
            value_of.setdefault(name, set()).add(value)
            name_of.setdefault(value, set()).add(name)
    if all(len(v) == 1 for v in value_of.values()) and all(len(n) == 1 for n in name_of.values()):
        ids = {name: next(iter(values)) for name, values in value_of.items()}
    else:
        order = sorted(value_of, key=lambda name: (min(value_of[name]), name))
        ids = {name: i + 1 for i, name in enumerate(order)}
    luts = {}
    for plant, names in maps.items():
        lut = np.zeros(256, dtype=np.uint8)
        for value, name in names.items():
            lut[value] = ids[name]
        luts[plant] = lut
    remapped = tuple(p for p, names in maps.items() if any(ids[n] != v for v, n in names.items()))
    categories = {i: name for name, i in sorted(ids.items(), key=lambda x: x[1])}
    return DatasetClasses(categories, luts, remapped)
