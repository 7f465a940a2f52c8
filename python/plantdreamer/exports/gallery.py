"""``gallery.png``: a contact sheet of a dataset (or one plant) to check it at a glance:
every plant's first view beside its label view, titled by plant id and species.

Drawn with matplotlib (Agg, no display needed). The grid is about square in plants
(ceil(sqrt(n)) pairs a row), so a thousand plants make a picture of a few thousand pixels a
side, not a strip. The PNG carries no software version, so the same folder gives the same
bytes with the same matplotlib.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantdreamer import atomic
from plantdreamer.errors import InputError
from plantdreamer.exports.instances import read_png, read_transforms
from plantdreamer.exports.listing import PLANTS_DIR, finished_plants, plant_species

GALLERY_FILE = "gallery.png"
PANEL_INCHES = 1.8  # one image, at 100 dpi
TITLE_INCHES = 0.25
MAX_PAIRS_PER_ROW = 12


@dataclass(frozen=True)
class Tile:
    title: str
    image: Path
    labels: Path | None  # the colour label preview; None for an unlabelled plant


def plant_tile(folder: Path, plant_id: str, species: str) -> Tile:
    """The first view of a plant folder and its label preview."""
    frames = read_transforms(folder)["frames"]
    if not frames:
        raise InputError(f"{folder} has no views")
    image = folder / frames[0]["file_path"]
    preview = folder / "labels" / "preview" / image.name
    return Tile(f"{plant_id} ({species})", image, preview if preview.is_file() else None)


def gallery_tiles(folder: Path) -> list[Tile]:
    """The tiles of a dataset folder (its finished plants, by id) or of one plant folder."""
    folder = Path(folder)
    if (folder / "transforms.json").is_file():
        species = plant_species(folder / "run.json") if (folder / "run.json").is_file() else "?"
        return [plant_tile(folder, folder.name, species)]
    if not (folder / PLANTS_DIR).is_dir():
        raise InputError(f"{folder} is neither a plant folder nor a dataset folder")
    tiles = [
        plant_tile(p.folder, p.id, p.species)
        for p in finished_plants(folder)
        if (p.folder / "transforms.json").is_file()
    ]
    if not tiles:
        raise InputError(f"{folder} has no finished plant with views to show")
    return tiles


def write_gallery(folder: Path, out: Path | None = None) -> Path:
    """Draws the contact sheet of ``folder`` into ``out`` (default: ``folder/gallery.png``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    tiles = gallery_tiles(folder)
    out = Path(out) if out is not None else Path(folder) / GALLERY_FILE
    per_row = min(len(tiles), MAX_PAIRS_PER_ROW, math.ceil(math.sqrt(len(tiles))))
    rows = math.ceil(len(tiles) / per_row)
    height = rows * (PANEL_INCHES + TITLE_INCHES)
    fig = Figure(figsize=(2 * per_row * PANEL_INCHES, height), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 2 * per_row, squeeze=False)
    fig.subplots_adjust(
        left=0.005, right=0.995, bottom=0.005, top=1 - TITLE_INCHES / height, wspace=0.03,
        hspace=TITLE_INCHES / PANEL_INCHES,
    )  # fmt: skip
    for ax in axes.reshape(-1):
        ax.set_axis_off()
    for i, tile in enumerate(tiles):
        row, col = divmod(i, per_row)
        left, right = axes[row, 2 * col], axes[row, 2 * col + 1]
        image = read_png(tile.image)[..., :3]
        left.imshow(image)
        left.set_title(tile.title, fontsize=8, loc="left")
        if tile.labels is not None:
            right.imshow(read_png(tile.labels)[..., :3])
        else:
            right.imshow(np.zeros_like(image))
            right.text(0.5, 0.5, "no labels", color="white", ha="center", fontsize=7,
                       transform=right.transAxes)  # fmt: skip
    atomic.atomic_write(
        out, lambda tmp: fig.savefig(tmp, format="png", metadata={"Software": None})
    )
    return out
