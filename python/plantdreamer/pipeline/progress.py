"""Progress display (a live bar on a terminal, plain periodic log lines otherwise) and the
per-phase timer whose totals go into run.json."""

from __future__ import annotations

import sys
import time
from collections import defaultdict
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

BAR_WIDTH = 16  # characters of a bar: the whole line fits an 80-column terminal


def duration_text(seconds: float) -> str:
    """``4.2 s``, ``5 min 12 s``, ``2 h 03 min``."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, secs = divmod(round(seconds), 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    return f"{minutes // 60} h {minutes % 60:02d} min"


class Progress:
    def __init__(self, total: int, start: int = 0, enabled: bool = True) -> None:
        self.total, self.start = total, start
        self.enabled = enabled
        self.t0 = time.perf_counter()
        self.every = max(1, total // 20)
        self._bar: Any = None
        if enabled and sys.stderr.isatty():
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                TextColumn,
                TimeRemainingColumn,
            )
            from rich.progress import Progress as RichProgress

            # Fits 80 columns: 8 + 16 + 11 (3600/3600) + at most 33 of info + 7.
            self._bar = RichProgress(
                TextColumn("[bold green]generate"),
                BarColumn(bar_width=BAR_WIDTH),
                MofNCompleteColumn(),
                TextColumn("{task.fields[info]}"),
                TimeRemainingColumn(),
                transient=False,
            )
            self._task = self._bar.add_task("", total=total, completed=start, info="")
            self._bar.start()

    def update(self, step: int, loss: float | None, gaussians: int) -> None:
        """``loss=None``: nothing is trained (no guidance); the line says what the step did
        instead of a zero loss and a meaningless rate."""
        if not self.enabled:
            return
        done = step + 1
        rate = (done - self.start) / max(time.perf_counter() - self.t0, 1e-9)
        if self._bar is not None:  # short: the bar's line fits 80 columns
            if loss is None:
                short = f"no guidance  {gaussians:,} G"
            else:
                short = f"loss {loss:<7.4g} {gaussians:,} G  {rate:.1f} it/s"
            self._bar.update(self._task, completed=done, info=short)
            return
        if loss is None:
            info = f"no training: density control and culling only  gaussians {gaussians}"
        else:
            info = f"loss {loss:.4g}  gaussians {gaussians}  {rate:.1f} it/s"
        if done % self.every == 0 or done == self.total:
            eta = (
                f"  eta {(self.total - done) / rate:.0f}s" if loss is not None and rate > 0 else ""
            )
            print(f"step {done}/{self.total}  {info}{eta}", file=sys.stderr, flush=True)

    def note(self, message: str) -> None:
        """One line about a phase of the run (initialisation, export)."""
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.console.print(message)
        else:
            print(message, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()


class Counter:
    """Progress of a phase that counts items (the export's views): a bar on a terminal, a
    line at each tenth otherwise, nothing when disabled. A with-block closes it."""

    def __init__(self, label: str, total: int, enabled: bool = True) -> None:
        self.label, self.total, self.done = label, total, 0
        self.enabled = enabled and total > 0
        self.every = max(1, total // 10)
        self._bar: Any = None
        if self.enabled and sys.stderr.isatty():
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn
            from rich.progress import Progress as RichProgress

            self._bar = RichProgress(
                TextColumn(f"[bold green]{label}"),
                BarColumn(bar_width=BAR_WIDTH),
                MofNCompleteColumn(),
                transient=True,
            )
            self._task = self._bar.add_task("", total=total)
            self._bar.start()

    def advance(self) -> None:
        if not self.enabled:
            return
        self.done += 1
        if self._bar is not None:
            self._bar.update(self._task, completed=self.done)
        elif self.done % self.every == 0 or self.done == self.total:
            print(f"{self.label} {self.done}/{self.total}", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()
            self._bar = None

    def __enter__(self) -> Counter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class PhaseTimer:
    """Seconds spent per phase of a run (``with timer("raster.forward"): ...``), summed;
    ``observers`` (a trainer's ``TrainerObserver``s) hear each phase start and end."""

    def __init__(self, totals: dict[str, float] | None = None) -> None:
        self.totals: dict[str, float] = defaultdict(float, totals or {})
        self.observers: Sequence[Any] = ()

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        for observer in self.observers:
            observer.phase_start(name)
        t0 = time.perf_counter()
        try:
            yield
        finally:
            seconds = time.perf_counter() - t0
            self.totals[name] += seconds
            for observer in self.observers:
                observer.phase_end(name, seconds)
