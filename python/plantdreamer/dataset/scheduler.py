"""Handing a dataset's units (single plants, or packed groups) to worker actors.

One pool of ``PlantWorker`` actors per distinct demand (CPUs, GPUs, custom resources), as
many as the cluster's live nodes hold at once and no more than there are units. A worker
has one unit in flight; when it returns, the worker takes its pool's next unit in plan
order, and a pool with nothing left releases its workers so that another pool's can
start. Which worker runs a unit never changes the unit's bytes (``worker.py``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

from plantdreamer.dataset import engine
from plantdreamer.dataset.plant import Plant
from plantdreamer.dataset.worker import PlantWorker


@dataclass
class Unit:
    """What one worker call trains: its plants (one, or a packed group) and its request."""

    plants: list[Plant]
    demand: engine.Demand
    request: dict[str, Any]


class Dispatcher:
    def __init__(
        self, ray: Any, units: list[Unit], board: Any, max_retries: int, extra_env: dict[str, str]
    ) -> None:
        self.ray, self.board = ray, board
        self.queues: dict[engine.Demand, deque[Unit]] = {}
        for unit in units:
            self.queues.setdefault(unit.demand, deque()).append(unit)
        self.pending: dict[Any, tuple[Any, Unit]] = {}  # call -> (worker, unit)
        worker_class = ray.remote(PlantWorker)
        for demand, queue in self.queues.items():
            options = demand.actor_options(max_retries, extra_env)
            for _ in range(min(len(queue), max(1, engine.capacity(demand)))):
                self._next(worker_class.options(**options).remote(), demand)

    def busy(self) -> bool:
        return bool(self.pending)

    def wait(self, timeout: float) -> list[tuple[Unit, Any]]:
        """The units that returned within ``timeout`` seconds, with their calls (for
        ``ray.get``); their workers take the next units."""
        if not self.pending:
            return []
        ready, _ = self.ray.wait(list(self.pending), num_returns=len(self.pending),
                                 timeout=timeout)  # fmt: skip
        finished = []
        for ref in ready:
            worker, unit = self.pending.pop(ref)
            finished.append((unit, ref))
            self._next(worker, unit.demand)
        return finished

    def drop_queued(self) -> None:
        """No unit starts after this (a stop); the running ones finish or checkpoint."""
        for queue in self.queues.values():
            queue.clear()

    def _next(self, worker: Any, demand: engine.Demand) -> None:
        queue = self.queues[demand]
        if not queue:
            self.ray.kill(worker)  # its resources go to the next pool's workers
            return
        unit = queue.popleft()
        self.pending[worker.run.remote(unit.request, self.board)] = (worker, unit)
