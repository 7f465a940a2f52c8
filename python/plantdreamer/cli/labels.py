"""``plantdreamer labels``: remake the label files of a plant or dataset folder."""

from __future__ import annotations

from pathlib import Path

import click

from plantdreamer.cli.label_options import label_options


@click.command()
@click.argument("folder", type=click.Path(exists=True, file_okay=False))
@label_options
def labels(
    folder: str,
    split_ratios: str,
    split_seed: int,
    split_mode: str,
    stuff: str,
    allow_empty_split: bool,
    min_instance_area: int,
) -> None:
    """Remake the label files from what generate wrote in FOLDER: for a plant folder its
    coco.json, yolo/ and points.ply; for a dataset folder splits.json, coco/, yolo/ and
    gallery.png (and each plant's own files when --min-instance-area changed)."""
    from plantdreamer.cli.label_options import describe, make_label_options
    from plantdreamer.errors import InputError
    from plantdreamer.exports import write_dataset_exports, write_plant_exports
    from plantdreamer.exports.plant import LABEL_FILES
    from plantdreamer.output_folder import LOCK_NAME, locked, survey
    from plantdreamer.source_date import source_date_epoch

    options = make_label_options(
        split_ratios, split_seed, min_instance_area, allow_empty_split, stuff, split_mode
    )
    root = Path(folder)
    source_date_epoch()  # the card's date: a malformed one refused before anything
    if (root / "run.json").is_file() and not (root / "transforms.json").is_file():
        raise InputError(f"{root} is a plant made with --eval-views 0: it has no views to label")
    # The lock of generate and dataset: never a folder a run is writing.
    with locked(root / LOCK_NAME, f"folder {root}"):
        if (root / "transforms.json").is_file():
            survey(root, LABEL_FILES).refuse(root)
            r = write_plant_exports(root, options.min_area, options.stuff)
            click.echo(f"{r.describe(options.min_area)}: {root}")
            return
        labels = write_dataset_exports(root, options)
    click.echo(describe(labels, folder))
