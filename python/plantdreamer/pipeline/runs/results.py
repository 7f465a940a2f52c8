"""What a run returns for each plant, and the error a front end raises when plants failed."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from plantdreamer.errors import PlantsFailed
from plantdreamer.pipeline.export import RunResult
from plantdreamer.pipeline.runs.record import DONE, PlantEntry


@dataclass(frozen=True)
class PlantResult:
    """A plant of a run: where it stands and, when done, what it wrote."""

    name: str
    folder: Path
    status: str  # record.DONE, FAILED or INTERRUPTED
    error: str | None = None  # FAILED: the one-line error
    steps: int = 0
    gaussians: int = 0  # DONE: in plant.ply
    timings: dict[str, float] = field(default_factory=dict)  # seconds per phase (run.json)
    resumed_from: int | None = None  # the checkpoint's step it continued from, if any
    trained_with: tuple[str, ...] = ()  # the plants of its trainer (itself included)
    retried: bool = False  # it had failed, and this resume tried it again

    @property
    def done(self) -> bool:
        return self.status == DONE

    @property
    def ply_path(self) -> Path:
        """The 3DGS model (written once the plant is done)."""
        return self.folder / "plant.ply"


def result_of(
    entry: PlantEntry,
    trained: RunResult | None,
    resumed_from: int | None,
    trained_with: tuple[str, ...],
    retried: bool,
) -> PlantResult:
    """``entry``'s result: ``trained`` in this run, or (done before) read from its run.json."""
    if entry.status == DONE and trained is None:
        trained = finished_result(entry.folder)
    if entry.status != DONE or trained is None:
        return PlantResult(
            entry.name, entry.folder, entry.status, entry.error,
            resumed_from=resumed_from, trained_with=trained_with, retried=retried,
        )  # fmt: skip
    return PlantResult(
        entry.name, entry.folder, DONE, None, trained.steps, trained.gaussians,
        dict(trained.timings), resumed_from, trained_with, retried,
    )  # fmt: skip


def finished_result(folder: Path) -> RunResult:
    """A finished plant's figures, from its run.json."""
    from plantdreamer.pipeline.settings.config import GenerateConfig

    run = json.loads((folder / "run.json").read_text())
    return RunResult(
        folder, folder / "plant.ply", GenerateConfig.from_dict(run["config"]).train.steps,
        run["gaussians"]["final"], run["timings_s"],
    )  # fmt: skip


def finished_or_raise(results: list[PlantResult], record_file: Path | None) -> list[PlantResult]:
    """``results`` when every plant is done; else ``PlantsFailed`` naming each failure
    (``record_file``: where the run recorded them)."""
    failed = [r for r in results if not r.done]
    if not failed:
        return results
    failures = "; ".join(f"{r.name}: {r.error}" for r in sorted(failed, key=lambda r: r.name))
    where = f"; see {record_file}" if record_file is not None else ""
    raise PlantsFailed(
        f"{len(failed)} of {len(results)} plants failed ({failures}){where}",
        [r for r in results if r.done],
    )
