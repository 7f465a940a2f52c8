"""``DIR/manifest.jsonl`` (one line per plant) and ``DIR/dataset.json`` (spec and totals).

Both files are rewritten whole and atomically at every change, so a reader (or a crash, or
Ctrl-C) never sees a half-written line. Plant statuses: ``running`` (started on a worker),
``done``, ``failed`` (its own error, one line) and ``interrupted`` (stopped by Ctrl-C; its
checkpoint is kept and the next run resumes it).
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

from plantdreamer.atomic import atomic_write
from plantdreamer.errors import InputError

MANIFEST_NAME = "manifest.jsonl"
SUMMARY_NAME = "dataset.json"
STATUSES = ("running", "done", "failed", "interrupted")


class Manifest:
    """The dataset's plant records, keyed by plant id, kept in first-seen order."""

    def __init__(self, out_dir: Path) -> None:
        self.path = out_dir / MANIFEST_NAME
        self.records: dict[str, dict[str, Any]] = {}
        if self.path.is_file():
            for number, line in enumerate(self.path.read_text().splitlines(), 1):
                if not line.strip():
                    continue
                try:
                    record = json.loads(line)
                    self.records[record["id"]] = record
                except (json.JSONDecodeError, KeyError, TypeError) as exc:
                    raise InputError(f"{self.path}:{number}: not a manifest line ({exc})") from None

    def get(self, plant_id: str) -> dict[str, Any] | None:
        return self.records.get(plant_id)

    def update(self, plant_id: str, **fields: Any) -> dict[str, Any]:
        """Merges ``fields`` into the plant's record and rewrites the file."""
        record = self.records.setdefault(plant_id, {"id": plant_id})
        record.update(fields)
        self.save()
        return record

    def replace(self, plant_id: str, record: dict[str, Any]) -> None:
        self.records[plant_id] = {"id": plant_id, **record}
        self.save()

    def save(self) -> None:
        text = "".join(json.dumps(r, sort_keys=True) + "\n" for r in self.records.values())
        atomic_write(self.path, lambda tmp: tmp.write_text(text))

    def counts(self, ids: list[str] | None = None) -> Counter[str]:
        records = self.records.values() if ids is None else (self.records.get(i) for i in ids)
        return Counter(r["status"] for r in records if r is not None)


def write_summary(out_dir: Path, summary: dict[str, Any]) -> None:
    text = json.dumps(summary, indent=2, sort_keys=True) + "\n"
    atomic_write(out_dir / SUMMARY_NAME, lambda tmp: tmp.write_text(text))


def totals(records: list[dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Plants per species (or ``pointcloud`` files) and status."""
    table: dict[str, dict[str, int]] = {}
    for r in records:
        row = table.setdefault(r.get("species") or "pointcloud", {})
        row[r["status"]] = row.get(r["status"], 0) + 1
    return table
