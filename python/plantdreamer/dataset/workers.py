"""Where a dataset's units run: the local pool on one machine, Ray for a cluster.

Without ``--address`` the plants run on worker processes this command starts on this
machine (``local_pool.py``); with ``--address auto|HOST:PORT`` on a Ray cluster it joins,
and with ``--address local`` on a private Ray it starts here (``ray_workers.py``,
``engine.py``). Both give the scheduler the same ``Workers``: long-lived workers that keep
their models loaded, one unit in flight each, start reports with attempt numbers, a stop
request the running units honour at their next step, and a lost worker's unit run again
up to ``max_retries`` times. A plant's bytes are the same on either.

Why the pool on one machine: what a local dataset waits for before its first plant can
start, measured on the 2-core benchmark machine under other work by
``benches/bench_dataset_start.py`` (BENCHMARKS.md, "Dataset start and early refusals";
min / median of 3 interleaved rounds, from the launch of a cold process): a worker that
has imported the pipeline took 22.9 / 40.9 s through a local Ray as ``--address local``
starts it, 18.6 / 21.0 s through a Ray started as lean as ``ray.init`` allows (no
prestarted worker, no metrics, no usage report, the smallest object store), and 6.2 /
13.7 s as the pool's process. Two ``--guidance none`` plants: the first started 7.9 / 8.0 s
after launch on the pool, 28.9 / 36.4 s on a local Ray; the whole command took 22.5 s
against 53.1 s (medians). Ray's start is its GCS, raylet and agents on the same two cores
the plants need (and its node can time out while starting on a loaded machine: "The
current node timed out during startup"); the pool is one process per worker, needs no
port, no token and no Ray installed, and a run with nothing to train starts none. Ray stays
for what only it does: several machines (and ``--address local``, to try a cluster's path
on one).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, Protocol

from plantdreamer.dataset.demand import LOCAL_MORE, Demand, check_fits


class Workers(Protocol):
    """What the scheduler (``scheduler.py``) and the runner ask of a place to run units."""

    nodes: int | None  # machines that may run workers (dataset.json records it)

    def check_feasible(self, demands: set[Demand]) -> None: ...

    def capacity(self, demand: Demand) -> int: ...

    def start(self, demand: Demand, max_retries: int, env: dict[str, str]) -> Any: ...

    def submit(self, worker: Any, request: dict[str, Any]) -> Any: ...

    def wait(self, calls: list[Any], timeout: float) -> list[Any]: ...

    def result(self, call: Any) -> dict[str, dict[str, Any]] | str: ...

    def release(self, worker: Any) -> None: ...

    def starts(self) -> list[dict[str, Any]]: ...

    def stop(self) -> None: ...


def local_resources(local_cpus: int | None) -> tuple[int, list[str]]:
    """This machine's CPUs for the plants (``local_cpus``, else all) and its GPUs
    (``CUDA_VISIBLE_DEVICES`` entries), counted without torch or Ray."""
    from plantdreamer.devices import visible_gpu_ids

    return local_cpus or os.cpu_count() or 1, visible_gpu_ids()


def check_before_start(address: str | None, local_cpus: int | None, demands: set[Demand]) -> None:
    """The refusals that need no running Ray, before any starts: on this machine (the
    pool, or a local Ray) every worker's demand fits it; for Ray, it is installed, its
    token is present and private (``ray_token.py``) and a cluster's address answers. A
    cluster's nodes are known only once it is joined (``Workers.check_feasible``)."""
    from plantdreamer.dataset import engine

    if address is None or address == engine.LOCAL_RAY:
        cpus, gpus = local_resources(local_cpus)
        check_fits(demands, [{"CPU": float(cpus), "GPU": float(len(gpus))}], "this machine",
                   LOCAL_MORE)  # fmt: skip
    if address is not None:
        from plantdreamer.dataset.ray_token import check_token

        engine.import_ray()
        check_token(local=address == engine.LOCAL_RAY)
        if address != engine.LOCAL_RAY:
            engine.check_reachable(address)


@contextmanager
def open_workers(address: str | None, local_cpus: int | None) -> Iterator[Workers]:
    """The local pool (``address`` None), or Ray started or joined; closed (the pool's
    processes ended, a Ray this call started stopped) when the block ends."""
    cpus, gpus = local_resources(local_cpus)
    if address is None:
        from plantdreamer.dataset.local_pool import LocalPool

        pool = LocalPool(cpus, gpus)
        try:
            yield pool
        finally:
            pool.close()
        return
    from plantdreamer.dataset.ray_workers import ray_workers

    with ray_workers(address, local_cpus, len(gpus)) as workers:
        yield workers
