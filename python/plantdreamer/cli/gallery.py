"""``plantdreamer gallery``: the contact sheet of a dataset, group or plant folder."""

from __future__ import annotations

import click

from plantdreamer.exports.gallery import MAX_PLANTS


@click.command()
@click.argument("folder", type=click.Path(exists=True, file_okay=False))
@click.option(
    "--out", type=click.Path(dir_okay=False), help="The PNG to write [default: FOLDER/gallery.png]."
)
@click.option(
    "--max-plants",
    type=int,
    default=MAX_PLANTS,
    show_default=True,
    help="The most plants drawn; more are sampled evenly over their ids.",
)
@click.option("--overwrite", is_flag=True, help="Replace the PNG if it exists.")
def gallery(folder: str, out: str | None, max_plants: int, overwrite: bool) -> None:
    """Draw FOLDER's gallery.png: each plant's first view beside its label view. FOLDER is a
    dataset folder, a `generate --seeds` group folder or one plant folder."""
    from pathlib import Path

    from plantdreamer.exports.gallery import GALLERY_FILE, write_gallery
    from plantdreamer.output_folder import new_file

    target = new_file(Path(folder) / GALLERY_FILE if out is None else out, "--out",
                      overwrite=overwrite)  # fmt: skip
    path = write_gallery(Path(folder), target, max_plants)
    click.echo(f"wrote {path}")
