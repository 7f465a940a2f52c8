"""``plantdreamer view``: an interactive 3DGS viewer in the browser (needs the viewer extra)."""

from __future__ import annotations

import click

from plantdreamer.viewer import DEFAULT_PORT, HOST


@click.command()
@click.argument("ply", type=click.Path(dir_okay=False))
@click.option("--labels", is_flag=True, help="Start coloured by organ label (if the PLY has them).")
@click.option("--port", default=DEFAULT_PORT, show_default=True, help=f"Port on {HOST}.")
def view(ply: str, labels: bool, port: int) -> None:
    """Serve PLY (a 3DGS model) on localhost for the browser; Ctrl-C stops it."""
    from plantdreamer.viewer.server import view_file

    view_file(ply, port, labels, echo=click.echo)
