"""Handing a dataset's units (single plants, or packed groups) to workers.

One pool of workers per distinct demand (CPUs, GPUs, custom resources), as many as the
machines hold at once and no more than there are units. A worker has one unit in flight;
when it returns, the worker takes its pool's next unit in plan order, and a pool with
nothing left releases its workers so that another pool's can start. The workers are the
local pool's processes or Ray actors (``workers.Workers``); which worker runs a unit never
changes the unit's bytes (``worker.py``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

from plantdreamer.dataset.demand import Demand
from plantdreamer.dataset.plant import Plant
from plantdreamer.dataset.workers import Workers


@dataclass
class Unit:
    """What one worker call trains: its plants (one, or a packed group) and its request."""

    plants: list[Plant]
    demand: Demand
    request: dict[str, Any]


class Dispatcher:
    def __init__(
        self, workers: Workers, units: list[Unit], max_retries: int, extra_env: dict[str, str]
    ) -> None:
        self.workers = workers
        self.queues: dict[Demand, deque[Unit]] = {}
        for unit in units:
            self.queues.setdefault(unit.demand, deque()).append(unit)
        self.pending: dict[Any, tuple[Any, Unit]] = {}  # call -> (worker, unit)
        for demand, queue in self.queues.items():
            for _ in range(min(len(queue), max(1, workers.capacity(demand)))):
                self._next(workers.start(demand, max_retries, extra_env), demand)

    def busy(self) -> bool:
        return bool(self.pending)

    def wait(self, timeout: float) -> list[tuple[Unit, Any]]:
        """The units that returned within ``timeout`` seconds, with their calls (for
        ``Workers.result``); their workers take the next units."""
        if not self.pending:
            return []
        finished = []
        for call in self.workers.wait(list(self.pending), timeout):
            worker, unit = self.pending.pop(call)
            finished.append((unit, call))
            self._next(worker, unit.demand)
        return finished

    def drop_queued(self) -> None:
        """No unit starts after this (a stop); the running ones finish or checkpoint."""
        for queue in self.queues.values():
            queue.clear()

    def _next(self, worker: Any, demand: Demand) -> None:
        queue = self.queues[demand]
        if not queue:
            self.workers.release(worker)  # its resources go to the next pool's workers
            return
        unit = queue.popleft()
        self.pending[self.workers.submit(worker, unit.request)] = (worker, unit)
