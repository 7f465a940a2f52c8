"""``gallery.png``: a contact sheet of a dataset, a ``generate --seeds`` group or one plant,
to check it at a glance: each plant's first view beside its label view, titled by plant id
and species.

Bounded whatever the dataset's size: at most ``MAX_PLANTS`` plants are drawn (12 x 12
pairs, 4320 x 2485 px), evenly spread over the plants sorted by id, and the sheet says so;
only the chosen plants' files are read, each image shrunk to its panel first. So 10,000
plants take seconds and tens of megabytes, not half an hour, gigabytes and a PNG too large
for Pillow to open (BENCHMARKS.md). Composed with Pillow (each panel pasted, titles in
Pillow's own font; matplotlib's 288 axes took most of the time); the grid is about square
in plants (ceil(sqrt(n)) pairs a row). The PNG carries no software version, so the same
folder gives the same bytes with the same Pillow.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantdreamer import atomic
from plantdreamer.errors import InputError
from plantdreamer.exports.instances import read_transforms
from plantdreamer.exports.listing import PLANTS_DIR, plant_species

GALLERY_FILE = "gallery.png"
GROUP_FILE = "group.json"  # a `generate --seeds` group folder (pipeline/runs/ writes it)
PANEL_INCHES = 1.8  # one image, at 100 dpi
DPI = 100
TITLE_INCHES = 0.25
MARGIN = 2  # white pixels around each picture in its panel
MAX_PAIRS_PER_ROW = 12
MAX_PLANTS = MAX_PAIRS_PER_ROW**2


@dataclass(frozen=True)
class Tile:
    title: str
    image: Path
    labels: Path | None  # the colour label preview; None for an unlabelled plant


def plant_tile(folder: Path, plant_id: str, species: str) -> Tile:
    """The first view of a plant folder and its label preview."""
    frames = read_transforms(folder).get("frames")
    if not frames or not isinstance(frames, list):
        raise InputError(f"{folder} has no views")
    if not isinstance(frames[0], dict) or not isinstance(frames[0].get("file_path"), str):
        raise InputError(f"{folder / 'transforms.json'}: frame 0 has no file_path")
    image = folder / frames[0]["file_path"]
    preview = folder / "labels" / "preview" / image.name
    return Tile(f"{plant_id} ({species})", image, preview if preview.is_file() else None)


def gallery_tiles(folder: Path, max_plants: int = MAX_PLANTS) -> tuple[list[Tile], int]:
    """The tiles of a dataset folder (its finished plants with views), a group folder or
    one plant folder: at most ``max_plants``, evenly spread over the plants by id; and how
    many plants there were to show."""
    folder = Path(folder)
    if max_plants < 1:
        raise InputError(f"--max-plants must be at least 1, got {max_plants}")
    if (folder / "transforms.json").is_file():
        return [plant_tile(folder, folder.name, _species(folder))], 1
    if (folder / "run.json").is_file():
        raise InputError(f"{folder} is a plant made with --eval-views 0: it has no views to show")
    if (folder / GROUP_FILE).is_file():
        finished = [p.parent for p in sorted(folder.glob("*/run.json"))]
    elif (folder / PLANTS_DIR).is_dir():
        finished = [p.parent for p in sorted((folder / PLANTS_DIR).glob("*/run.json"))]
    else:
        raise InputError(
            f"{folder} is neither a plant folder, a group folder (generate --seeds) nor a "
            "dataset folder"
        )
    shown = [p for p in finished if (p / "transforms.json").is_file()]
    if not shown:
        more = " (made with --eval-views 0)" if finished else ""
        raise InputError(f"{folder} has no finished plant with views to show{more}")
    chosen = [shown[i] for i in evenly(len(shown), max_plants)]
    return [plant_tile(p, p.name, _species(p)) for p in chosen], len(shown)


def evenly(n: int, k: int) -> list[int]:
    """``min(n, k)`` distinct indices of ``range(n)`` spread evenly, the first included."""
    return list(range(n)) if n <= k else [i * n // k for i in range(k)]


def _species(plant_dir: Path) -> str:
    run_json = plant_dir / "run.json"
    return plant_species(run_json) if run_json.is_file() else "?"


def write_gallery(folder: Path, out: Path | None = None, max_plants: int = MAX_PLANTS) -> Path:
    """Draws the contact sheet of ``folder`` into ``out`` (default: ``folder/gallery.png``)."""
    from PIL import Image, ImageDraw, ImageFont

    tiles, total = gallery_tiles(folder, max_plants)
    out = Path(out) if out is not None else Path(folder) / GALLERY_FILE
    per_row = min(len(tiles), MAX_PAIRS_PER_ROW, math.ceil(math.sqrt(len(tiles))))
    rows = math.ceil(len(tiles) / per_row)
    side, title = round(PANEL_INCHES * DPI), round(TITLE_INCHES * DPI)
    header = title if total > len(tiles) else 0
    sheet = Image.new("RGB", (2 * per_row * side, header + rows * (title + side)), "white")
    draw = ImageDraw.Draw(sheet)
    font = ImageFont.load_default(size=11)
    if header:
        text = f"{len(tiles)} of {total} plants, evenly spread over their ids"
        draw.text((4, header // 2), text, fill="black", font=font, anchor="lm")
    for i, tile in enumerate(tiles):
        row, col = divmod(i, per_row)
        x, y = 2 * col * side, header + row * (title + side)
        draw.text((x + 2, y + title // 2), tile.title, fill="black", font=font, anchor="lm")
        image = _panel(tile.image, side - 2 * MARGIN)
        _paste(sheet, image, x, y + title, side)
        if tile.labels is not None:
            _paste(sheet, _panel(tile.labels, side - 2 * MARGIN), x + side, y + title, side)
        else:
            h, w = image.shape[:2]
            x0, y0 = x + side + (side - w) // 2, y + title + (side - h) // 2
            draw.rectangle((x0, y0, x0 + w - 1, y0 + h - 1), fill="black")
            draw.text((x0 + w // 2, y0 + h // 2), "no labels", fill="white", font=font,
                      anchor="mm")  # fmt: skip
    atomic.atomic_write(out, lambda tmp: sheet.save(tmp, format="PNG"))
    return out


def _paste(sheet, image: np.ndarray, x: int, y: int, side: int) -> None:
    """``image`` centred in the ``side``-pixel panel at ``(x, y)``."""
    from PIL import Image

    h, w = image.shape[:2]
    sheet.paste(Image.fromarray(image), (x + (side - w) // 2, y + (side - h) // 2))


def _panel(path: Path, side: int) -> np.ndarray:
    """An image's RGB shrunk to fit a ``side``-pixel panel (never enlarged): a sheet of
    large renders holds panel-sized copies, not every full image."""
    from PIL import Image

    try:
        with Image.open(path) as file:
            image = file.convert("RGB")
        image.thumbnail((side, side), Image.Resampling.LANCZOS)
        return np.asarray(image)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable image ({exc})") from None
