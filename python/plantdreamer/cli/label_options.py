"""The options that shape a dataset's label files, shared by ``dataset`` and ``labels``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import click

# Literal copies of exports' defaults would drift; these are read from there (light imports).
from plantdreamer.exports.instances import MIN_INSTANCE_AREA
from plantdreamer.exports.splits import DEFAULT_RATIOS, DEFAULT_SEED


def label_options(command: Callable[..., Any]) -> Callable[..., Any]:
    """Adds --split, --split-seed and --min-instance-area."""
    for option in reversed(
        (
            click.option(
                "--split",
                "split_ratios",
                default=",".join(f"{r:g}" for r in DEFAULT_RATIOS),
                show_default=True,
                metavar="TRAIN,VAL,TEST",
                help="Shares of plants in the train, val and test splits (whole plants).",
            ),
            click.option(
                "--split-seed",
                type=click.IntRange(0),
                default=DEFAULT_SEED,
                show_default=True,
                help="Seed of the split.",
            ),
            click.option(
                "--min-instance-area",
                type=click.IntRange(1),
                default=MIN_INSTANCE_AREA,
                show_default=True,
                help="Objects of fewer pixels are left out of COCO, YOLO and the torch Dataset.",
            ),
        )
    ):
        command = option(command)
    return command


def make_label_options(split_ratios: str, split_seed: int, min_instance_area: int):
    """The ``LabelOptions`` of the parsed values."""
    from plantdreamer.exports.dataset import LabelOptions
    from plantdreamer.exports.splits import parse_ratios

    return LabelOptions(parse_ratios(split_ratios), split_seed, min_instance_area)


def describe(labels) -> str:
    """One line about a dataset's label files (a ``DatasetLabels``)."""
    sizes = ", ".join(f"{len(ids)} {split}" for split, ids in labels.splits.items())
    r = labels.report
    return (
        f"splits: {sizes} plants; {r.objects} objects in {r.images} images "
        f"({r.dropped} under the area limit left out); gallery: {labels.gallery}"
    )
