"""A dataset's workers on Ray (``--address``): one ``PlantWorker`` actor per worker, the
status board as an actor beside them, and Ray's errors as one line.

Ray restarts a worker actor that dies and runs its unit again, up to ``max_retries``
times, resuming from the checkpoints; a plant's own error is never retried (it comes back
as a record). Every Ray call of the driver goes through ``_one_line``: whatever Ray raises
there (a lost head, a dead board) becomes a ``RayStartError`` with Ray's first line, never
Ray's traceback.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from plantdreamer.dataset import engine
from plantdreamer.dataset.demand import Demand
from plantdreamer.dataset.tasks import StatusBoard, first_line
from plantdreamer.dataset.worker import PlantWorker


class RayBoard:
    """The status board actor as a worker sees it (``tasks.Board``): reports go without
    waiting for an answer."""

    def __init__(self, handle: Any) -> None:
        self.handle = handle

    def started(self, plant_id: str, info: dict[str, Any]) -> None:
        self.handle.started.remote(plant_id, info)

    def stopping(self) -> bool:
        import ray

        return bool(ray.get(self.handle.stopping.remote()))


class RayPlantWorker(PlantWorker):
    """A ``PlantWorker`` as a Ray actor: its board comes as the board actor's handle."""

    def run(self, unit: dict[str, Any], board: Any) -> dict[str, dict[str, Any]]:  # type: ignore[override]
        return super().run(unit, RayBoard(board))


def actor_options(demand: Demand, max_retries: int, extra_env: dict[str, str]) -> dict[str, Any]:
    """A worker actor's options: restarted whenever it dies, its unit retried
    ``max_retries`` times."""
    return {
        "num_cpus": demand.cpus,
        "num_gpus": demand.gpus,
        "resources": dict(demand.custom),
        "max_restarts": -1,
        "max_task_retries": max_retries,
        "runtime_env": {"env_vars": {**demand.thread_env(), **extra_env}},
    }


@contextmanager
def _one_line(what: str) -> Iterator[None]:
    import ray

    try:
        yield
    except ray.exceptions.RayError as exc:
        raise engine.RayStartError(f"Ray failed while {what} ({first_line(exc)})") from None


class RayWorkers:
    """The ``workers.Workers`` of a Ray instance this process is connected to."""

    def __init__(self, ray: Any) -> None:
        self.ray = ray
        with _one_line("starting the status board"):
            self.board = ray.remote(num_cpus=0)(StatusBoard).remote()
            self.nodes: int | None = engine.alive_nodes()
        self.worker_class = ray.remote(RayPlantWorker)

    def check_feasible(self, demands: set[Demand]) -> None:
        with _one_line("listing the nodes"):
            engine.check_feasible(demands)

    def capacity(self, demand: Demand) -> int:
        with _one_line("listing the nodes"):
            return engine.capacity(demand)

    def start(self, demand: Demand, max_retries: int, env: dict[str, str]) -> Any:
        options = actor_options(demand, max_retries, env)
        with _one_line("starting a worker"):
            return self.worker_class.options(**options).remote()

    def submit(self, worker: Any, request: dict[str, Any]) -> Any:
        with _one_line("handing a worker its plants"):
            return worker.run.remote(request, self.board)

    def wait(self, calls: list[Any], timeout: float) -> list[Any]:
        if not calls:
            return []
        with _one_line("waiting for the workers"):
            ready, _ = self.ray.wait(calls, num_returns=len(calls), timeout=timeout)
        return list(ready)

    def result(self, call: Any) -> dict[str, dict[str, Any]] | str:
        """The unit's records, or one line saying why its worker was lost for good."""
        try:
            return dict(self.ray.get(call))
        except self.ray.exceptions.RayError as exc:  # the worker died more often than retried
            return first_line(exc)

    def release(self, worker: Any) -> None:
        with _one_line("releasing a worker"):
            self.ray.kill(worker)

    def starts(self) -> list[dict[str, Any]]:
        with _one_line("reading the status board"):
            return list(self.ray.get(self.board.drain.remote()))

    def stop(self) -> None:
        with _one_line("asking the workers to stop"):
            self.board.stop.remote()


@contextmanager
def ray_workers(address: str, local_cpus: int | None, local_gpus: int) -> Iterator[RayWorkers]:
    """Ray started (``address`` "local") or joined, its workers; a Ray this call started
    stops when the block ends."""
    ray = engine.import_ray()
    started = engine.connect(address, local_cpus, local_gpus)
    try:
        yield RayWorkers(ray)
    finally:
        if started:
            ray.shutdown()
