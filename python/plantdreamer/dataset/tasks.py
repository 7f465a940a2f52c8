"""What a dataset worker runs: a unit of plants (one, or a packed group) as one run of the
pipeline's entry (``generate_plants`` with the unit's folders: ``GivenFolders``), each plant
in its own dataset folder with its own record in the manifest, and the board workers
report to.

These are plain functions and classes, run by a process of the local pool or a Ray actor
(``ray_workers.py`` wraps them), so this module imports without Ray. A plant's own errors
never raise: they come back as a ``failed`` record with one line.
"""

from __future__ import annotations

import io
import os
import socket
import time
import traceback
from collections.abc import Callable
from contextlib import ExitStack, redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any, Protocol

LOG_NAME = "generate.log"
HELD_MARKER = ".held"  # a plant the test hook held once (its retry runs through)
# Test hook: "PLANT_ID:STEP" makes that plant (or its group) stop after STEP, once, and
# wait to be killed, so tests can SIGKILL a worker at a known point of its run.
HOLD_ENV = "PLANTDREAMER_DATASET_HOLD"

# Builds the guidance of plants' shared settings (a worker's model cache, or
# `build_guidance`).
GuidanceFor = Callable[[Any], Any]
StepHook = Callable[[int], None]


class Board(Protocol):
    """The driver as a worker sees it: where a unit reports that a plant started, and asks
    whether the driver wants the run to stop."""

    def started(self, plant_id: str, info: dict[str, Any]) -> None: ...

    def stopping(self) -> bool: ...


class StatusBoard:
    """Collects "plant started on this worker" reports for the driver, and carries the
    driver's request to stop back to the workers (a Ray actor).

    Counting starts per plant gives the attempt number: Ray runs a call again after its
    worker dies, and the retry reports a second start. Workers report without waiting for
    an answer.
    """

    def __init__(self) -> None:
        self.events: list[dict[str, Any]] = []
        self.attempts: dict[str, int] = {}
        self.stop_requested = False

    def started(self, plant_id: str, info: dict[str, Any]) -> None:
        attempt = self.attempts.get(plant_id, 0) + 1
        self.attempts[plant_id] = attempt
        self.events.append({"id": plant_id, "attempt": attempt, **info})

    def drain(self) -> list[dict[str, Any]]:
        events, self.events = self.events, []
        return events

    def stop(self) -> None:
        self.stop_requested = True

    def stopping(self) -> bool:
        return self.stop_requested


def worker_info() -> dict[str, Any]:
    import sys

    ray = sys.modules.get("ray")  # a Ray actor's node; none in the local pool (no import)
    node = ray.get_runtime_context().get_node_id() if ray and ray.is_initialized() else None
    return {"pid": os.getpid(), "node": node, "host": socket.gethostname(), "started": time.time()}


def run_unit(
    request: dict[str, Any], board: Board, guidance_for: GuidanceFor, on_step: StepHook | None
) -> dict[str, dict[str, Any]]:
    """Trains a unit's plants together (one plant is a unit of one), each in its own
    dataset folder; returns each plant's record. A plant with a checkpoint resumes from it
    (plants stopped at different steps resume apart, each where it stopped); a plant's own
    failure fails it alone."""
    from plantdreamer.pipeline import GenerateConfig, GivenFolders, RunInterrupted, generate_plants

    plants = request["plants"]
    threads = int(request["threads"])  # the rasterizer's; torch's are the plants' setting
    info = worker_info()
    for plant in plants:
        board.started(plant["id"], info)
    ids = [p["id"] for p in plants]
    dirs = [Path(p["plant_dir"]) for p in plants]
    hidden = folder_not_visible(dirs[0], info)
    if hidden is not None:
        return {i: failed_record(info, hidden) for i in ids}
    t0 = time.perf_counter()
    with ExitStack() as stack:
        for folder in dirs:
            folder.mkdir(parents=True, exist_ok=True)
        tee = _Tee([stack.enter_context(open(d / LOG_NAME, "a")) for d in dirs])
        stack.enter_context(redirect_stdout(tee))
        stack.enter_context(redirect_stderr(tee))
        print(f"== group of {len(plants)} ({', '.join(ids)}), pid {info['pid']}, "
              f"threads {threads}")  # fmt: skip
        hold = next((h for i, d in zip(ids, dirs, strict=True)
                     if (h := hold_hook(i, d, tee)) is not None), None)  # fmt: skip
        try:
            results = generate_plants(
                [GenerateConfig.from_dict(p["config"]) for p in plants],
                dirs[0].parent,
                layout=GivenFolders(tuple(dirs)),
                failures="record",
                resume=True,
                guidance_for=guidance_for,
                show_progress=True,
                on_step=chain_hooks([on_step, hold]),
            )
        except RunInterrupted as stop:  # the plants failed before the stop stay failed
            failed = {r.name: r.error for r in stop.results if r.status == "failed"}
            stopped = {**info, "status": "interrupted", "error": f"interrupted at step {stop.step}"}
            return {i: failed_record(info, failed[i]) if i in failed else stopped for i in ids}
        except Exception as exc:  # the unit could not start (models, settings): each plant fails
            traceback.print_exc()
            return {i: failed_record(info, f"{type(exc).__name__}: {exc}") for i in ids}
        done = sum(r.done for r in results)
        print(f"done: {done} of {len(ids)} plants in {time.perf_counter() - t0:.1f} s")
    records = {}
    for plant_id, result in zip(ids, results, strict=True):
        if result.done:
            record = done_record(info, t0, result.resumed_from, result)
            records[plant_id] = {**record, "trained_with": list(result.trained_with)}
        else:
            records[plant_id] = failed_record(info, result.error or "unknown error")
    return records


class _Tee(io.TextIOBase):
    """A unit's output, written to every plant's log."""

    def __init__(self, files: list[Any]) -> None:
        self.files = files

    def isatty(self) -> bool:
        return False

    def write(self, text: str) -> int:  # type: ignore[override]
        for f in self.files:
            f.write(text)
        return len(text)

    def flush(self) -> None:
        for f in self.files:
            f.flush()


def folder_not_visible(plant_dir: Path, info: dict[str, Any]) -> str | None:
    from plantdreamer.dataset.lock import LOCK_NAME

    if plant_dir.parent.parent.joinpath(LOCK_NAME).exists():
        return None
    return (
        f"output folder {plant_dir.parent.parent} is not visible on this node "
        f"({info['host']}); a cluster needs it on a shared filesystem"
    )


def done_record(info, t0, resumed_from, result) -> dict[str, Any]:
    from plantdreamer import _core

    return {
        **info,
        "status": "done",
        "error": None,
        "finished": time.time(),
        "seconds": round(time.perf_counter() - t0, 3),
        "resumed_from_step": resumed_from,
        "raster_threads": int(_core.info()["threads"]),
        "gaussians": _gaussian_counts(result.folder, result.gaussians),
        "timings_s": {k: round(v, 3) for k, v in result.timings.items()},
    }


def failed_record(info: dict[str, Any], message: str) -> dict[str, Any]:
    lines = message.strip().splitlines() or ["unknown error"]
    return {**info, "status": "failed", "error": lines[0], "finished": time.time()}


def _gaussian_counts(plant_dir: Path, final: int) -> dict[str, int]:
    import json

    run = json.loads((plant_dir / "run.json").read_text())
    return {"initial": int(run["gaussians"]["initial"]), "final": final}


def chain_hooks(hooks: list[StepHook | None]) -> StepHook | None:
    present = [h for h in hooks if h is not None]
    if not present:
        return None

    def each(step: int) -> None:
        for hook in present:
            hook(step)

    return each


def hold_hook(plant_id: str, plant_dir: Path, log: Any) -> StepHook | None:
    target = os.environ.get(HOLD_ENV, "")
    marker = plant_dir / HELD_MARKER
    if marker.exists() or not target.startswith(f"{plant_id}:"):
        return None
    hold_step = int(target.rsplit(":", 1)[1])

    def hold(step: int) -> None:
        if step == hold_step:
            marker.touch()
            print(f"holding after step {step} until killed", flush=True)
            log.flush()
            while True:
                time.sleep(1.0)

    return hold


def first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".strip()
