"""The traits as tables, one CSV row per image or per plant or leaf, as leaf-counting and
trait-regression sets give them: ``counts.csv`` in a plant folder (one row per view: its
visible leaves and the plant's size in pixels), and in a dataset folder
``counts/<split>.csv`` (the same per image), ``traits/<split>.csv`` (one row per plant:
traits.json's ``plant``) and ``traits/<split>_leaves.csv`` (one row per leaf)."""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from plantdreamer import atomic

COUNTS_FILE = "counts.csv"
COUNTS_DIR = "counts"
TRAITS_DIR = "traits"
# The columns after the image's (and a dataset's plant id): traits.views.view_fields.
FIGURES = ("leaf_count", "plant_area_px", "plant_height_px", "plant_width_px", "metres_per_pixel")
# traits.json's plant figures in a dataset's table, and its leaves' (a scan has fewer).
PLANT_COLUMNS = (
    "species", "seed", "stage", "leaf_count", "leaf_area", "height", "canopy_width",
    "canopy_hull_area", "stem_count",
)  # fmt: skip
LEAF_COLUMNS = (
    "instance", "area", "length", "width", "inclination", "azimuth", "base_height",
    "node_height", "stem", "shoot", "emerged", "new", "count",
)  # fmt: skip


def write_counts(path: Path, first: Sequence[str], rows: Sequence[Mapping[str, Any]]) -> None:
    """A CSV of ``rows`` with the columns ``first`` (``file_name``, ...), then ``FIGURES``;
    an unknown figure is an empty cell."""
    write_table(path, (*first, *FIGURES), rows)


def write_table(path: Path, columns: Sequence[str], rows: Sequence[Mapping[str, Any]]) -> None:
    """A CSV of ``rows`` in ``columns`` (a missing value: an empty cell), written atomically."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([_cell(row.get(key)) for key in columns])
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_text(path, text.getvalue())


def plant_row(record: Mapping[str, Any]) -> dict[str, Any]:
    """traits.json's plant figures as a row of ``PLANT_COLUMNS``."""
    plant = dict(record.get("plant", {}))
    plant["stage"] = plant.get("growth", {}).get("stage")
    return {key: plant.get(key) for key in PLANT_COLUMNS}


def leaf_rows(record: Mapping[str, Any]) -> list[dict[str, Any]]:
    """traits.json's leaves as rows of ``LEAF_COLUMNS``."""
    return [{key: leaf.get(key) for key in LEAF_COLUMNS} for leaf in record.get("leaves", [])]


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)
    return str(value)
