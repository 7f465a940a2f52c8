"""A dataset folder's own top-level files: the record that says a dataset wrote them, the
check before any is replaced, and the swap that replaces them as a whole.

- **Whose files.** ``splits.json``, ``gallery.png``, ``dataset.json``, ``coco/``, ``yolo/``
  and the swap's marker are the dataset's once the folder holds its record
  (``dataset.json`` with what ``dataset`` or the card wrote in it). In a folder without
  one, any of them that exists is a user's: the command is refused with the list before
  anything is written (``README.md`` is not among them: one that is not a card is left as
  it is, with a warning).
- **Whole or marked.** The new files are built in a staging folder, then moved in by one
  rename each (a file over the old one in one step; a folder after the old one is moved
  aside). Before the first rename ``export.incomplete`` is written, and it is removed
  after the last: a process killed between two renames leaves the folder saying that its
  label files are a mix, ``PlantViews`` refuses it, and the next ``labels`` or ``dataset``
  run makes them whole. Outside that window the folder holds the previous export or the
  new one, each whole.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterable
from pathlib import Path

from plantdreamer import atomic
from plantdreamer.errors import InputError
from plantdreamer.exports.card import CARD_KEY, SUMMARY_FILE

__all__ = ["INCOMPLETE", "check_incomplete", "check_top_files", "holds_record", "swap_in"]

INCOMPLETE = "export.incomplete"
# Keys only a dataset's own record has: the run's (dataset/runner.py) or the card's.
_RECORD_KEYS = (CARD_KEY, "spec")


def holds_record(folder: Path) -> bool:
    """Whether ``folder`` holds a dataset's record: ``dataset.json``, a JSON object with
    what ``dataset`` or the card writes in it."""
    try:
        record = json.loads((Path(folder) / SUMMARY_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(record, dict) and any(key in record for key in _RECORD_KEYS)


def check_top_files(folder: Path, names: Iterable[str]) -> None:
    """Refuses a folder without a dataset's record that holds any of ``names`` (the
    top-level files and folders the dataset writes): they are a user's, and nothing is
    written. A folder with the record: they are the dataset's own."""
    folder = Path(folder)
    if holds_record(folder):
        return
    there = [n for n in names if (folder / n).exists() or (folder / n).is_symlink()]
    if there:
        raise InputError(
            f"{folder} holds {', '.join(there)}, which a dataset writes, but no dataset record "
            f"({SUMMARY_FILE} as `plantdreamer dataset` writes it): they are not a dataset's; "
            "nothing was written: move them away, or choose another folder"
        )


def check_incomplete(folder: Path) -> None:
    """Refuses a dataset folder whose label files were left a mix by a stopped swap."""
    marker = Path(folder) / INCOMPLETE
    if marker.exists():
        raise InputError(
            f"{folder}'s label files were being replaced when the process stopped ({marker}): "
            f"they may mix two exports; run `plantdreamer labels {folder}` to make them whole"
        )


def swap_in(folder: Path, stage: Path, replaced: Iterable[str], added: Iterable[str]) -> None:
    """Moves ``added`` (each only when the stage holds it; first, so the dataset's record
    is in before any other file) and ``replaced`` (each goes, whether or not the stage
    holds a new one) from ``stage`` into ``folder``, between the marker's writing and its
    removal (see the module's docstring)."""
    names = [*(n for n in added if (stage / n).exists()), *replaced]
    marker = folder / INCOMPLETE
    atomic.write_text(
        marker,
        "The label files of this folder are being replaced; if this file stays, the process "
        "stopped in between: run `plantdreamer labels` on this folder.\n",
    )
    retired = stage / ".retired"
    retired.mkdir()
    for name in names:
        new, old = stage / name, folder / name
        if new.is_file() and not old.is_dir():  # a file over a file: one atomic step
            os.replace(new, old)
            continue
        if old.exists() or old.is_symlink():
            os.rename(old, retired / name)
        if new.exists():
            os.rename(new, old)
    marker.unlink()
    atomic.fsync_folder(folder)
    shutil.rmtree(stage)
