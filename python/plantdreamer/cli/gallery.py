"""``plantdreamer gallery``: the contact sheet of a dataset or plant folder."""

from __future__ import annotations

import click


@click.command()
@click.argument("folder", type=click.Path(exists=True, file_okay=False))
@click.option(
    "--out", type=click.Path(dir_okay=False), help="The PNG to write [default: FOLDER/gallery.png]."
)
def gallery(folder: str, out: str | None) -> None:
    """Draw FOLDER's gallery.png: each plant's first view beside its label view."""
    from pathlib import Path

    from plantdreamer.exports.gallery import write_gallery

    click.echo(f"wrote {write_gallery(Path(folder), None if out is None else Path(out))}")
