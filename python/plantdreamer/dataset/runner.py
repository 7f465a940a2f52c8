"""Runs a dataset: plan (``plan.py``: skip, resume, redo), hand plants to workers (the
local pool, or Ray with an address: ``workers.py``), record results.

Every plant is one `generate` run into ``DIR/plants/<id>/``; with ``plants_per_gpu`` B > 1,
plants that share their settings train B at a time in one trainer (``packing.py``), each
still in its own folder with its own record, and a plant that fails, fails alone. The
units go to long-lived workers that keep the models loaded (``scheduler.py``,
``worker.py``). Every refusal that needs no running Ray (settings, models, resources,
the token) comes before any worker or Ray starts, and a run with nothing left to train
starts none: it only remakes the exports.

Nothing outside ``DIR`` is written or deleted: plant ids are checked folder names
(``dataset.spec``), and a plant folder must resolve to a direct child of ``DIR/plants``.
Ctrl-C and SIGTERM both stop cleanly: running plants checkpoint and stop, and their records
say ``interrupted``.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plantdreamer.dataset.demand import Demand, plant_demand
from plantdreamer.dataset.display import DatasetProgress, print_summary
from plantdreamer.dataset.lock import dataset_lock
from plantdreamer.dataset.manifest import Manifest, totals, write_summary
from plantdreamer.dataset.plan import base_record, check_models, plan, work_units
from plantdreamer.dataset.plant import Plant
from plantdreamer.dataset.scenes import ScenePlan, make_dataset_scenes
from plantdreamer.dataset.scheduler import Dispatcher, Unit
from plantdreamer.dataset.tasks import HOLD_ENV
from plantdreamer.dataset.workers import Workers, check_before_start, open_workers
from plantdreamer.errors import DatasetStopped
from plantdreamer.exports.dataset import (
    DATASET_EXPORTS,
    DatasetLabels,
    LabelOptions,
    check_exports_owned,
    check_planned_splits,
    write_dataset_exports,
)
from plantdreamer.output_folder import remove_temporaries
from plantdreamer.output_locks import HELD_ENV, held_tokens
from plantdreamer.stop_signals import stop_signals_handled
from plantdreamer.versions import package_versions

# After Ctrl-C or SIGTERM, how long running plants get to write their checkpoint and stop.
STOP_GRACE_S = 60.0
STOPPED = "stopped by Ctrl-C or SIGTERM"


@dataclass
class RunOptions:
    address: str | None = None  # None: the local pool; "local": a local Ray; else a cluster
    local_cpus: int | None = None  # CPUs of this machine for the plants (None: all)
    cpus_per_plant: float | None = None
    gpus_per_plant: float | None = None
    resources: dict[str, float] = field(default_factory=dict)  # custom, per plant
    max_retries: int = 3  # re-runs of a plant whose worker died
    plants_per_gpu: int = 1  # plants trained together in one trainer (packing.py)
    show_progress: bool = True
    labels: LabelOptions = field(default_factory=LabelOptions)  # splits, COCO, YOLO, gallery
    redo_changed: bool = False  # delete and remake finished plants of other settings
    scenes: list[ScenePlan] = field(default_factory=list)  # made once the plants are done


@dataclass
class DatasetReport:
    out_dir: Path
    done: int
    failed: int
    skipped: int
    interrupted: int
    seconds: float
    failures: dict[str, str]
    labels: DatasetLabels | None = None  # None: no plant finished

    @property
    def ok(self) -> bool:
        return self.failed == 0 and self.interrupted == 0


def run_dataset(
    spec: dict[str, Any], plants: list[Plant], out_dir: str | Path, options: RunOptions
) -> DatasetReport:
    out_dir = Path(out_dir).resolve()
    # SIGTERM (a scheduler's notice before a kill) stops the run as Ctrl-C does.
    with stop_signals_handled(_interrupt), dataset_lock(out_dir):
        return _DatasetRun(spec, plants, out_dir, options).run()


def _interrupt(_signum: int, _frame: object) -> None:
    raise KeyboardInterrupt


class _DatasetRun:
    def __init__(
        self, spec: dict[str, Any], plants: list[Plant], out_dir: Path, options: RunOptions
    ) -> None:
        self.spec, self.plants, self.out_dir, self.options = spec, plants, out_dir, options
        self.manifest = Manifest(out_dir)
        self.by_id = {p.id: p for p in plants}
        self.t0 = time.time()
        self.nodes: int | None = None

    def run(self) -> DatasetReport:
        # Everything checked before _plan clears any folder: the export folders are the
        # dataset's own, the models are there, the plants' demands fit.
        check_exports_owned(self.out_dir)
        remove_temporaries(self.out_dir, DATASET_EXPORTS)  # a killed run's temporaries
        check_models(self.plants)
        demands = {
            p.id: plant_demand(
                p.config,
                self.options.cpus_per_plant,
                self.options.gpus_per_plant,
                self.options.resources,
                self.options.plants_per_gpu,
            )
            for p in self.plants
        }
        check_before_start(self.options.address, self.options.local_cpus, set(demands.values()))
        # A split the plants would leave empty: refused before any plant runs.
        check_planned_splits(
            self.out_dir,
            {p.id: p.species_name for p in self.plants},
            self.options.labels,
            planned_classes(self.plants),
        )
        todo, skipped = plan(
            self.plants,
            self.manifest,
            self.out_dir,
            self.options.plants_per_gpu,
            self.options.redo_changed,
        )
        self._write_summary("running", skipped)
        results: dict[str, dict[str, Any]] = {}
        state = "stopped"
        stopped = False
        try:
            if todo:
                results = self._run_units(todo, demands)
            state = "finished"
        except KeyboardInterrupt:
            stopped = True  # recorded below, then raised again with the report
        finally:
            for plant in todo:  # still running after a stop: its checkpoint is what is left
                if self._status(plant.id) == "running":
                    self.manifest.update(plant.id, status="interrupted", error=STOPPED)
            if self.manifest.lines > len(self.manifest.records):
                self.manifest.compact()
            self._write_summary(state, skipped)
        seconds = time.time() - self.t0
        ids = [p.id for p in todo]
        counts = self.manifest.counts(ids)
        records = [
            self.manifest.records[p.id] for p in self.plants if p.id in self.manifest.records
        ]
        ran = counts["done"] + counts["failed"] if stopped else len(results)
        if self.options.show_progress:
            print_summary(totals(records), len(skipped), ran, seconds)
        report = DatasetReport(
            self.out_dir,
            counts["done"],
            counts["failed"],
            len(skipped),
            counts["interrupted"],
            seconds,
            {i: r["error"] for i, r in results.items() if r["status"] == "failed"},
        )
        if stopped:  # no label files: a stop is quick, and the next run writes them
            raise DatasetStopped(report)
        if counts["done"] or skipped:
            notes = make_dataset_scenes(self.out_dir, self.options.scenes, self.options.labels)
            report.labels = write_dataset_exports(self.out_dir, self.options.labels)
            report.labels.warnings.extend(notes)
        return report

    def _status(self, plant_id: str) -> str | None:
        record = self.manifest.get(plant_id)
        return None if record is None else record.get("status")

    # -- scheduling --------------------------------------------------------------------

    def _run_units(
        self, todo: list[Plant], demands: dict[str, Demand]
    ) -> dict[str, dict[str, Any]]:
        options = self.options
        with open_workers(options.address, options.local_cpus) as workers:
            units = work_units(self.plants, todo, demands, self.out_dir, options.plants_per_gpu)
            workers.check_feasible({u.demand for u in units})
            self.nodes = workers.nodes
            extra_env = {HOLD_ENV: os.environ[HOLD_ENV]} if HOLD_ENV in os.environ else {}
            extra_env[HELD_ENV] = ",".join(held_tokens())  # workers write inside our lock
            dispatcher = Dispatcher(workers, units, options.max_retries, extra_env)
            return self._follow(workers, dispatcher, [p.id for p in todo])

    def _follow(
        self, workers: Workers, dispatcher: Dispatcher, ids: list[str]
    ) -> dict[str, dict[str, Any]]:
        results: dict[str, dict[str, Any]] = {}
        progress = DatasetProgress(len(ids), self.options.show_progress)
        try:
            while dispatcher.busy():
                finished = dispatcher.wait(timeout=0.5)
                self._record_starts(workers.starts(), set(results))
                for unit, call in finished:
                    for plant, result in self._record_unit(workers, unit, call).items():
                        results[plant] = result
                        progress.finished(plant, result)
                progress.update(self.manifest.counts(ids))
        except KeyboardInterrupt:
            progress.close()
            self._stop(workers, dispatcher, results)
            raise
        finally:
            progress.close()
        return results

    def _record_starts(self, events: list[dict[str, Any]], finished: set[str]) -> None:
        for event in events:
            plant = self.by_id[event["id"]]
            if plant.id in finished:  # the report came after the result: keep the result
                self.manifest.update(plant.id, attempt=event["attempt"])
                continue
            self.manifest.replace(
                plant.id,
                {**base_record(plant, self.options.plants_per_gpu), **event, "status": "running"},
            )

    def _record_unit(self, workers: Workers, unit: Unit, call: Any) -> dict[str, dict[str, Any]]:
        results = workers.result(call)
        if isinstance(results, str):  # the worker died more often than retried
            results = {p.id: {"status": "failed", "error": results} for p in unit.plants}
        for plant in unit.plants:
            record = self.manifest.get(plant.id)
            if record is None or record.get("status") != "running":  # a late start report
                record = base_record(plant, self.options.plants_per_gpu)
            record = {"finished": time.time(), **record, **results[plant.id]}
            self.manifest.replace(plant.id, {k: v for k, v in record.items() if k != "id"})
        return {p.id: results[p.id] for p in unit.plants}

    def _stop(self, workers: Workers, dispatcher: Dispatcher, results) -> None:
        """Ctrl-C or SIGTERM: ask the running units to checkpoint and stop (the workers
        poll for it), start no other, then record what happened."""
        workers.stop()
        dispatcher.drop_queued()
        deadline = time.time() + STOP_GRACE_S
        try:
            while dispatcher.busy() and time.time() < deadline:
                finished = dispatcher.wait(timeout=0.5)
                self._record_starts(workers.starts(), set(results))
                for unit, call in finished:
                    results.update(self._record_unit(workers, unit, call))
        except KeyboardInterrupt:  # a second Ctrl-C: stop waiting
            pass

    # -- dataset.json ------------------------------------------------------------------

    def _write_summary(self, state: str, skipped: list[Plant]) -> None:
        records = [
            self.manifest.records[p.id] for p in self.plants if p.id in self.manifest.records
        ]
        write_summary(
            self.out_dir,
            {
                "state": state,
                "spec": self.spec,
                "plants": len(self.plants),
                "skipped": len(skipped),
                "plants_per_gpu": self.options.plants_per_gpu,
                "totals": totals(records),
                "started": self.t0,
                "seconds": round(time.time() - self.t0, 3),
                "workers": {
                    "on": "local pool" if self.options.address is None else "ray",
                    "address": self.options.address,
                    "nodes": self.nodes,
                },
                "versions": package_versions(("plantdreamer", "ray", "torch", "numpy")),
            },
        )


def planned_classes(plants: list[Plant]) -> list[str] | None:
    """The class names the plants' label files will have: an L-System's organs; None when
    a plant comes from a point cloud (its classes are known once it is read)."""
    if any(p.config.source.pointcloud is not None for p in plants):
        return None
    from plantdreamer.lsystem import OrganClass

    return [c.name.lower() for c in OrganClass]
