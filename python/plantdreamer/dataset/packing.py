"""Packing a dataset's plants into groups trained together on one GPU (``plants-per-gpu``).

A group is up to B plants that share every setting but their seed and point cloud
(``pipeline.settings.config.PER_PLANT``): one trainer, one batched guidance call per step. Plants are
taken in spec order; each joins the first open group of its settings, and a group closes
when it holds B. The packing depends only on the spec (all its plants, finished or not),
so a rerun finds every plant in the group it started in: an interrupted group resumes as
the same group, and the same spec gives the same bytes. Plants that cannot share (other
settings) get groups of their own; a group of one is a plant without packing (one path).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from plantdreamer import settings
from plantdreamer.errors import InputError
from plantdreamer.pipeline.settings.group_settings import MAX_GROUP_PLANTS
from plantdreamer.settings import by_name, canonical, setting

if TYPE_CHECKING:
    from plantdreamer.dataset.plant import Plant

MAX_PLANTS_PER_GPU = MAX_GROUP_PLANTS  # the most plants one trainer holds


@dataclass
class PackingConfig:
    """How a dataset's plants share a GPU; a setting of the spec's top level and a
    `dataset` option, by the same name."""

    plants_per_gpu: int = setting(
        1,
        "Plants trained together in one trainer on one GPU (one batched network call per "
        "step); such a group asks for B x --cpus-per-plant CPUs and --gpus-per-plant GPUs.",
        range=(1, MAX_PLANTS_PER_GPU),
    )


def packing_from(spec: dict[str, Any], given: dict[str, Any]) -> PackingConfig:
    """The spec's top-level packing settings with the command line's ``given`` over them."""
    known = by_name(PackingConfig)
    values = {canonical(k): v for k, v in spec.items() if canonical(k) in known}
    values.update({k: v for k, v in given.items() if v is not None})
    config = PackingConfig(**{known[k].param: v for k, v in values.items()})
    try:  # the limits the command line applies, for the spec's values too
        settings.check_types(config)
        settings.check_choices(config)
    except ValueError as exc:
        raise InputError(f"spec: {exc}") from None
    return config


def spec_keys() -> set[str]:
    """The top-level spec keys this module reads (as written: ``-`` or ``_``)."""
    names = set(by_name(PackingConfig))
    return names | {n.replace("-", "_") for n in names}


def pack(plants: list[Plant], plants_per_gpu: int) -> list[list[Plant]]:
    """The groups, in the order of their first plants (see the module docstring)."""
    groups: list[list[Plant]] = []
    open_group: dict[str, list[Plant]] = {}
    for plant in plants:
        key = _shared_settings(plant)
        group = open_group.get(key)
        if group is None or len(group) >= plants_per_gpu:
            group = open_group[key] = []
            groups.append(group)
        group.append(plant)
    return groups


def _shared_settings(plant: Plant) -> str:
    return json.dumps(plant.config.shared_settings(), sort_keys=True)
