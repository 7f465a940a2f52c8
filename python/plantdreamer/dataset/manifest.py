"""``DIR/manifest.jsonl`` (one record per plant) and ``DIR/dataset.json`` (spec and totals).

Each change of a plant appends its whole record as one line, so the driver's cost per change
does not grow with the dataset (rewriting the file at every change took hours of driver
time at 10,000 plants). A plant may then appear on several lines: the last one counts. The
file is compacted to one line per plant, atomically, when a run opens it, when appended
lines outnumber plants three to one, and when the run ends. A line cut short by a killed
driver (the last line, without its newline) is dropped at the next open. Appends are
flushed to the operating system, not fsynced: a power cut may lose the latest changes,
which is safe because a rerun checks each plant's files, not only its record.

Plant statuses: ``pending`` (planned; any other config's files are being cleared),
``running`` (started on a worker), ``done``, ``failed`` (its own error, one line) and
``interrupted`` (stopped by Ctrl-C or SIGTERM; its checkpoint is kept and the next run
resumes it). The per-plant file list is not in the record: the plant's folder is the list.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from pathlib import Path
from typing import Any

from plantdreamer.atomic import atomic_write
from plantdreamer.errors import InputError
from plantdreamer.exports.card import CARD_KEY, SUMMARY_FILE

MANIFEST_NAME = "manifest.jsonl"
SUMMARY_NAME = SUMMARY_FILE
STATUSES = ("pending", "running", "done", "failed", "interrupted")
# Compaction when the file holds this many lines per plant (plus a few, for tiny datasets).
COMPACT_RATIO = 3
_COMPACT_SLACK = 64


class Manifest:
    """The dataset's plant records, keyed by plant id, kept in first-seen order."""

    def __init__(self, out_dir: Path, read_only: bool = False) -> None:
        """Reads ``out_dir``'s records; ``read_only``: never compacts the file (a dry run)."""
        self.path = out_dir / MANIFEST_NAME
        self.records: dict[str, dict[str, Any]] = {}
        self.lines = 0  # lines in the file, for deciding when to compact
        if self.path.is_file():
            text = self.path.read_bytes()
            lines = text.split(b"\n")
            torn = lines.pop()  # b"" after a final newline; else a line cut short
            for number, line in enumerate(lines, 1):
                if line.strip():
                    record = _parse(line, f"{self.path}:{number}")
                    self.records[record["id"]] = record
            self.lines = len(lines)
            if (torn or self.lines > len(self.records)) and not read_only:
                self.compact()

    def get(self, plant_id: str) -> dict[str, Any] | None:
        return self.records.get(plant_id)

    def update(self, plant_id: str, **fields: Any) -> dict[str, Any]:
        """Merges ``fields`` into the plant's record and writes it."""
        record = self.records.setdefault(plant_id, {"id": plant_id})
        record.update(fields)
        self._append(record)
        return record

    def replace(self, plant_id: str, record: dict[str, Any]) -> None:
        self.records[plant_id] = {"id": plant_id, **record}
        self._append(self.records[plant_id])

    def compact(self) -> None:
        """Rewrites the file atomically with one line per plant."""
        text = "".join(_line(r) for r in self.records.values())
        atomic_write(self.path, lambda tmp: tmp.write_text(text))
        self.lines = len(self.records)

    def _append(self, record: dict[str, Any]) -> None:
        if self.lines >= COMPACT_RATIO * len(self.records) + _COMPACT_SLACK:
            self.compact()
            return
        data = _line(record).encode()
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        try:
            written = os.write(fd, data)
            while written < len(data):  # a short write (a signal): finish the line
                written += os.write(fd, data[written:])
        finally:
            os.close(fd)
        self.lines += 1

    def counts(self, ids: list[str] | None = None) -> Counter[str]:
        records = self.records.values() if ids is None else (self.records.get(i) for i in ids)
        return Counter(r["status"] for r in records if r is not None)


def _line(record: dict[str, Any]) -> str:
    return json.dumps(record, sort_keys=True) + "\n"


def _parse(line: bytes, where: str) -> dict[str, Any]:
    try:
        record = json.loads(line)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{where}: not a manifest line ({exc})") from None
    if not isinstance(record, dict) or not isinstance(record.get("id"), str):
        raise InputError(f"{where}: not a manifest line (no plant 'id')")
    if record.get("status") not in STATUSES:
        raise InputError(
            f"{where}: plant {record['id']!r} has status {record.get('status')!r}, not one of "
            f"{', '.join(STATUSES)}; fix or delete the line (a plant whose finished files are "
            "there is then kept, any other runs again)"
        )
    return record


def write_summary(out_dir: Path, summary: dict[str, Any]) -> None:
    """``dataset.json``; the card the last label export wrote there is kept (it describes
    the label files on disk until the next export remakes both)."""
    try:
        card = json.loads((out_dir / SUMMARY_NAME).read_text()).get(CARD_KEY)
    except (OSError, ValueError, AttributeError):
        card = None
    if card is not None:
        summary = {**summary, CARD_KEY: card}
    text = json.dumps(summary, indent=2, sort_keys=True) + "\n"
    atomic_write(out_dir / SUMMARY_NAME, lambda tmp: tmp.write_text(text))


def totals(records: list[dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Plants per species (or ``pointcloud`` files) and status."""
    table: dict[str, dict[str, int]] = {}
    for r in records:
        row = table.setdefault(r.get("species") or "pointcloud", {})
        row[r["status"]] = row.get(r["status"], 0) + 1
    return table
