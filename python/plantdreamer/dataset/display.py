"""What the terminal shows: one live bar of plants, then a summary table."""

from __future__ import annotations

import sys
import time
from collections import Counter
from typing import Any

from plantdreamer.pipeline.progress import duration_text


class DatasetProgress:
    """A rich bar (done / failed / running, ETA) on a terminal; one line per finished plant
    otherwise. Plant logs never reach the terminal: they are in each plant's folder."""

    def __init__(self, total: int, enabled: bool) -> None:
        self.total, self.enabled = total, enabled
        self.finished_count, self.t0 = 0, time.monotonic()
        self._bar: Any = None
        if enabled and sys.stderr.isatty():
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
            from rich.progress import Progress as RichProgress

            self._bar = RichProgress(
                TextColumn("[bold green]dataset"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("{task.fields[info]}"),
                TimeRemainingColumn(),
            )
            self._task = self._bar.add_task("", total=total, info="")
            self._bar.start()

    def update(self, counts: Counter[str]) -> None:
        if self._bar is None:
            return
        finished = counts["done"] + counts["failed"]
        info = f"done {counts['done']}  failed {counts['failed']}  running {counts['running']}"
        self._bar.update(self._task, completed=finished, info=info)

    def finished(self, plant_id: str, record: dict[str, Any]) -> None:
        """Log mode (no terminal: Slurm, nohup): ``[k/N]``, the plant, and the time left at
        the rate of the plants finished so far."""
        self.finished_count += 1
        if not self.enabled or self._bar is not None:
            return
        k, n = self.finished_count, self.total
        detail = record.get("error") or f"{record.get('seconds', 0):.1f} s"
        left = (time.monotonic() - self.t0) / k * (n - k)
        eta = f"  eta {duration_text(left)}" if k < n else ""
        print(f"[{k}/{n}] {record['status']:<11} {plant_id}  {detail}{eta}",
              file=sys.stderr, flush=True)  # fmt: skip

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()


def print_summary(
    totals: dict[str, dict[str, int]], skipped: int, ran: int, seconds: float
) -> None:
    from rich.console import Console
    from rich.table import Table

    statuses = ("done", "failed", "interrupted", "running", "pending")
    # The table, with the run's rate under it; the command's last line says the rest (done,
    # skipped, the folder) once.
    rate = ran / seconds * 3600 if seconds > 0 and ran else 0.0
    table = Table(
        title="dataset",
        caption=f"{ran} run in {seconds:.1f} s ({rate:.1f} plants/hour), {skipped} skipped",
    )
    table.add_column("species")
    for status in statuses:
        table.add_column(status, justify="right")
    for species, row in sorted(totals.items()):
        table.add_row(species, *(str(row.get(s, 0)) for s in statuses))
    Console(stderr=True).print(table)
