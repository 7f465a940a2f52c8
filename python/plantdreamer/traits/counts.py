"""Per-view counts as leaf-counting sets give them: a CSV with one row per image (its file,
then the visible leaves and the plant's size in pixels), ``counts.csv`` in a plant folder
and ``counts/<split>.csv`` in a dataset folder."""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from plantdreamer import atomic

COUNTS_FILE = "counts.csv"
COUNTS_DIR = "counts"
# The columns after the image's (and a dataset's plant id): traits.views.view_fields.
FIGURES = ("leaf_count", "plant_area_px", "plant_height_px", "plant_width_px", "metres_per_pixel")


def write_counts(path: Path, first: Sequence[str], rows: Sequence[Mapping[str, Any]]) -> None:
    """A CSV of ``rows`` with the columns ``first`` (``file_name``, ...), then ``FIGURES``;
    an unknown figure is an empty cell."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow([*first, *FIGURES])
    for row in rows:
        writer.writerow([_cell(row.get(key)) for key in (*first, *FIGURES)])
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_text(path, text.getvalue())


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)
    return str(value)
