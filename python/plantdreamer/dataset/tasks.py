"""What runs on a Ray worker: one plant as one `generate`, and the board workers report to.

These are plain functions and classes; the runner wraps them with ``ray.remote`` so this
module imports without Ray.
"""

from __future__ import annotations

import os
import socket
import time
import traceback
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

LOG_NAME = "generate.log"
# Test hook: "PLANT_ID:STEP" makes that plant stop after STEP, once, and wait to be killed,
# so tests can SIGKILL a worker at a known point of its run.
HOLD_ENV = "PLANTDREAMER_DATASET_HOLD"


class StatusBoard:
    """Collects "plant started on this worker" reports for the driver (a Ray actor).

    Counting starts per plant gives the attempt number: Ray runs a task again after its
    worker dies, and the retry reports a second start. Workers report without waiting for
    an answer: a task blocked in ``ray.get`` lends its CPU back to Ray, which then starts
    another worker process for the next plant.
    """

    def __init__(self) -> None:
        self.events: list[dict[str, Any]] = []
        self.attempts: dict[str, int] = {}

    def started(self, plant_id: str, info: dict[str, Any]) -> None:
        attempt = self.attempts.get(plant_id, 0) + 1
        self.attempts[plant_id] = attempt
        self.events.append({"id": plant_id, "attempt": attempt, **info})

    def drain(self) -> list[dict[str, Any]]:
        events, self.events = self.events, []
        return events


def run_plant(request: dict[str, Any], board: Any) -> dict[str, Any]:
    """Runs (or resumes, when its folder holds a checkpoint) one plant; never raises for
    the plant's own errors: they come back as a ``failed`` record with one line."""
    import ray
    import torch

    from plantdreamer import _core
    from plantdreamer.dataset.lock import LOCK_NAME
    from plantdreamer.pipeline import GenerateConfig, RunInterrupted, generate
    from plantdreamer.pipeline.checkpoint import CHECKPOINT_NAME

    plant_id, plant_dir = request["id"], Path(request["plant_dir"])
    threads = int(request["threads"])
    torch.set_num_threads(threads)
    context = ray.get_runtime_context()
    info = {
        "pid": os.getpid(),
        "node": context.get_node_id(),
        "host": socket.gethostname(),
        "started": time.time(),
    }
    board.started.remote(plant_id, info)
    if not plant_dir.parent.parent.joinpath(LOCK_NAME).exists():
        return _failed(
            info,
            f"output folder {plant_dir.parent.parent} is not visible on this node "
            f"({info['host']}); a cluster needs it on a shared filesystem",
        )
    plant_dir.mkdir(parents=True, exist_ok=True)
    resume = (plant_dir / CHECKPOINT_NAME).is_file()
    resumed_from = None
    if resume:
        from plantdreamer.pipeline.checkpoint import load_checkpoint

        resumed_from = int(load_checkpoint(plant_dir)["step"])
    t0 = time.perf_counter()
    with open(plant_dir / LOG_NAME, "a") as log, redirect_stdout(log), redirect_stderr(log):
        print(f"== plant {plant_id}, pid {info['pid']}, threads {threads}")
        if resumed_from is not None:
            print(f"resuming from the checkpoint at step {resumed_from}")
        on_step = _hold_hook(plant_id, plant_dir, log)
        try:
            cfg = None if resume else GenerateConfig.from_dict(request["config"])
            # The plant folder is the dataset's (it holds this log): a fresh start replaces
            # whatever an earlier, incomplete attempt left there.
            result = generate(
                cfg,
                plant_dir,
                resume=resume,
                overwrite=not resume,
                show_progress=True,
                on_step=on_step,
            )
        except RunInterrupted as stop:
            return {**info, "status": "interrupted", "error": f"interrupted at step {stop.step}"}
        except Exception as exc:  # the plant's own failure: record it, keep the others going
            traceback.print_exc()
            return _failed(info, f"{type(exc).__name__}: {exc}")
        print(f"done: {result.gaussians} Gaussians in {time.perf_counter() - t0:.1f} s")
    return {
        **info,
        "status": "done",
        "error": None,
        "finished": time.time(),
        "seconds": round(time.perf_counter() - t0, 3),
        "resumed_from_step": resumed_from,
        "raster_threads": int(_core.info()["threads"]),
        "gaussians": _gaussian_counts(plant_dir, result.gaussians),
        "timings_s": {k: round(v, 3) for k, v in result.timings.items()},
    }


def _failed(info: dict[str, Any], message: str) -> dict[str, Any]:
    lines = message.strip().splitlines() or ["unknown error"]
    return {**info, "status": "failed", "error": lines[0], "finished": time.time()}


def _gaussian_counts(plant_dir: Path, final: int) -> dict[str, int]:
    import json

    run = json.loads((plant_dir / "run.json").read_text())
    return {"initial": int(run["gaussians"]["initial"]), "final": final}


def _hold_hook(plant_id: str, plant_dir: Path, log: Any):
    target = os.environ.get(HOLD_ENV, "")
    marker = plant_dir / ".held"  # the plant held once: its retry runs through
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
