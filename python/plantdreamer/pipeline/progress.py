"""Progress display: a live bar on a terminal, plain periodic log lines otherwise."""

from __future__ import annotations

import sys
import time
from typing import Any


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

            self._bar = RichProgress(
                TextColumn("[bold green]generate"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("{task.fields[info]}"),
                TimeRemainingColumn(),
                transient=False,
            )
            self._task = self._bar.add_task("", total=total, completed=start, info="")
            self._bar.start()

    def update(self, step: int, loss: float, gaussians: int) -> None:
        if not self.enabled:
            return
        done = step + 1
        rate = (done - self.start) / max(time.perf_counter() - self.t0, 1e-9)
        info = f"loss {loss:.4g}  gaussians {gaussians}  {rate:.1f} it/s"
        if self._bar is not None:
            self._bar.update(self._task, completed=done, info=info)
        elif done % self.every == 0 or done == self.total:
            eta = (self.total - done) / rate if rate > 0 else float("inf")
            print(f"step {done}/{self.total}  {info}  eta {eta:.0f}s", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()
