"""``traits.json`` on disk: its name, the atomic writer (NaN as null: strict JSON) and the
reader; torch-free, so what lists a run's files reads it without loading torch."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer import atomic
from plantdreamer.errors import InputError

TRAITS_FILE = "traits.json"
FORMAT = 1  # the layout of traits.json (docs/traits.md)


def write_traits(path: Path, record: dict[str, Any]) -> None:
    """Writes ``record`` (NaN as null: strict JSON)."""
    atomic.write_json(path, _finite(record), indent=1)


def read_traits(folder: Path) -> dict[str, Any] | None:
    """A plant folder's traits.json (None: it has none)."""
    path = Path(folder) / TRAITS_FILE
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path} is not valid JSON (cut short or damaged: {exc})") from None
    if not isinstance(record, dict) or not isinstance(record.get("views", []), list):
        raise InputError(f"{path} is not a traits file (no record of views)")
    return record


def recorded_views(record: dict[str, Any] | None) -> dict[str, dict[str, Any]]:
    """The views of a traits record by their render's path."""
    if record is None:
        return {}
    return {str(v.get("file_path")): v for v in record.get("views", []) if isinstance(v, dict)}


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, np.generic):
        return _finite(value.item())
    return value
