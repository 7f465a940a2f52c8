"""The options that shape a dataset's label files, shared by ``dataset`` and ``labels``."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

# Literal copies of exports' defaults would drift; these are read from there (light imports),
# the least values from the dataset request (the Python API checks the same).
from plantdreamer.dataset.request import OPTION_LIMITS
from plantdreamer.exports.card import README_FILE as CARD_FILE
from plantdreamer.exports.instances import MIN_INSTANCE_AREA
from plantdreamer.exports.splits import DEFAULT_MODE, DEFAULT_RATIOS, DEFAULT_SEED, SPLIT_MODES


def label_options(command: Callable[..., Any]) -> Callable[..., Any]:
    """Adds --split, --split-seed, --split-mode, --stuff, --allow-empty-split and
    --min-instance-area."""
    for option in reversed(
        (
            click.option(
                "--split",
                "split_ratios",
                default=",".join(f"{r:g}" for r in DEFAULT_RATIOS),
                show_default=True,
                metavar="TRAIN,VAL,TEST",
                help="Shares of plants in the train, val and test splits (whole plants): "
                "expected shares, each plant drawing its split, unless --split-mode exact.",
            ),
            click.option(
                "--split-seed",
                type=click.IntRange(int(OPTION_LIMITS["split_seed"][1])),
                default=DEFAULT_SEED,
                show_default=True,
                help="Seed of the split.",
            ),
            click.option(
                "--split-mode",
                type=click.Choice(SPLIT_MODES),
                default=DEFAULT_MODE,
                show_default=True,
                help="draw: each plant draws its split from its id and the seed, so a plant "
                "keeps its split as the dataset grows and the shares hold on average; exact: "
                "each species' counts (and each split's total) within one plant of the shares, "
                "a few plants moving when plants are added.",
            ),
            click.option(
                "--stuff",
                default="",
                metavar="NAMES",
                help="Classes that are no objects, comma-separated (e.g. pot,soil): COCO, "
                "YOLO and the torch Dataset's targets leave them out; the class maps keep them.",
            ),
            click.option(
                "--allow-empty-split",
                is_flag=True,
                help="Warn, not stop, when a split with a share draws no plant.",
            ),
            click.option(
                "--min-instance-area",
                type=click.IntRange(int(OPTION_LIMITS["min_instance_area"][1])),
                default=MIN_INSTANCE_AREA,
                show_default=True,
                help="Objects of fewer pixels are ignore regions: COCO iscrowd 1, left out of "
                "YOLO and the torch Dataset's targets.",
            ),
        )
    ):
        command = option(command)
    return command


def make_label_options(
    split_ratios: str,
    split_seed: int,
    min_instance_area: int,
    allow_empty_split: bool = False,
    stuff: str = "",
    split_mode: str = DEFAULT_MODE,
):
    """The ``LabelOptions`` of the parsed values."""
    from plantdreamer.exports.dataset import LabelOptions
    from plantdreamer.exports.splits import parse_ratios

    names = tuple(dict.fromkeys(n.strip() for n in stuff.split(",") if n.strip()))
    return LabelOptions(
        parse_ratios(split_ratios), split_seed, min_instance_area, allow_empty_split, names,
        split_mode,
    )  # fmt: skip


def describe(labels, folder: str) -> str:
    """A dataset's label files in a few lines (a ``DatasetLabels``): per split the plants
    of each species, the objects, the gallery and the card under FOLDER as the user typed
    it, then warnings."""
    parts = []
    for split, ids in labels.splits.items():
        species = ", ".join(f"{n} {name}" for name, n in labels.species.get(split, {}).items())
        parts.append(f"{len(ids)} {split}" + (f" ({species})" if species else ""))
    lines = [f"splits: {'; '.join(parts)} plants"]
    if any(labels.scenes.values()):
        lines[0] += "; scenes " + ", ".join(f"{len(i)} {s}" for s, i in labels.scenes.items())
    lines += [
        labels.report.describe(labels.min_area),
        f"gallery: {Path(folder) / labels.gallery.name}",
        f"card: {Path(folder) / CARD_FILE} (classes, splits, models, licences, citation)",
    ]
    lines += [f"warning: {w}" for w in labels.warnings]
    return "\n".join(lines)
