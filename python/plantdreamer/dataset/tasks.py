"""What a dataset worker runs: one plant as one `generate` (a packed group is
``group_task.py``), the records both return, and the board workers report to.

These are plain functions and classes; the runner wraps them with ``ray.remote`` so this
module imports without Ray. A plant's own errors never raise: they come back as a
``failed`` record with one line.
"""

from __future__ import annotations

import copy
import os
import socket
import time
import traceback
from collections.abc import Callable
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

LOG_NAME = "generate.log"
# Test hook: "PLANT_ID:STEP" makes that plant (or its group) stop after STEP, once, and
# wait to be killed, so tests can SIGKILL a worker at a known point of its run.
HOLD_ENV = "PLANTDREAMER_DATASET_HOLD"

# Builds the guidance of a resolved config (a worker's model cache, or `build_guidance`).
GuidanceFor = Callable[[Any], Any]
StepHook = Callable[[int], None]


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
    try:
        import ray

        node = ray.get_runtime_context().get_node_id() if ray.is_initialized() else None
    except ImportError:
        node = None
    return {"pid": os.getpid(), "node": node, "host": socket.gethostname(), "started": time.time()}


def run_plant(
    request: dict[str, Any], board: Any, guidance_for: GuidanceFor, on_step: StepHook | None
) -> dict[str, Any]:
    """Runs (or resumes, when its folder holds a checkpoint) one plant."""
    from plantdreamer.pipeline import GenerateConfig, RunInterrupted, generate
    from plantdreamer.pipeline.checkpoint import CHECKPOINT_NAME, load_checkpoint

    plant_id, plant_dir = request["id"], Path(request["plant_dir"])
    threads = set_threads(request)
    info = worker_info()
    board.started.remote(plant_id, info)
    hidden = folder_not_visible(plant_dir, info)
    if hidden is not None:
        return failed_record(info, hidden)
    plant_dir.mkdir(parents=True, exist_ok=True)
    resume = (plant_dir / CHECKPOINT_NAME).is_file()
    t0 = time.perf_counter()
    with open(plant_dir / LOG_NAME, "a") as log, redirect_stdout(log), redirect_stderr(log):
        print(f"== plant {plant_id}, pid {info['pid']}, threads {threads}")
        on_steps = [on_step, hold_hook(plant_id, plant_dir, log)]
        saved, resumed_from = None, None
        try:
            if resume:
                saved = load_checkpoint(plant_dir)
                resumed_from = int(saved["step"])
                print(f"resuming from the checkpoint at step {resumed_from}")
            cfg = GenerateConfig.from_dict(request["config"])
            guidance = guidance_for(resolved_config(cfg, saved))
            # The plant folder is the dataset's (it holds this log): a fresh start replaces
            # whatever an earlier, incomplete attempt left there.
            result = generate(
                None if resume else cfg,
                plant_dir,
                guidance=guidance,
                resume=resume,
                overwrite=not resume,
                show_progress=True,
                on_step=chain_hooks(on_steps),
            )
        except RunInterrupted as stop:
            return {**info, "status": "interrupted", "error": f"interrupted at step {stop.step}"}
        except Exception as exc:  # the plant's own failure: record it, keep the others going
            traceback.print_exc()
            return failed_record(info, f"{type(exc).__name__}: {exc}")
        print(f"done: {result.gaussians} Gaussians in {time.perf_counter() - t0:.1f} s")
    return {**done_record(info, t0, resumed_from, plant_dir, result), "trained_with": [plant_id]}


def resolved_config(cfg: Any, saved: dict[str, Any] | None) -> Any:
    """The config the run will use (a checkpoint's, or ``cfg`` with the machine's choices
    filled), which decides the guidance."""
    from plantdreamer.pipeline import GenerateConfig
    from plantdreamer.pipeline.runtime import resolve_runtime

    if saved is not None:
        return GenerateConfig.from_dict(saved["config"])
    cfg = copy.deepcopy(cfg)
    resolve_runtime(cfg)
    return cfg


def set_threads(request: dict[str, Any]) -> int:
    import torch

    threads = int(request["threads"])
    torch.set_num_threads(threads)
    return threads


def folder_not_visible(plant_dir: Path, info: dict[str, Any]) -> str | None:
    from plantdreamer.dataset.lock import LOCK_NAME

    if plant_dir.parent.parent.joinpath(LOCK_NAME).exists():
        return None
    return (
        f"output folder {plant_dir.parent.parent} is not visible on this node "
        f"({info['host']}); a cluster needs it on a shared filesystem"
    )


def done_record(info, t0, resumed_from, plant_dir: Path, result) -> dict[str, Any]:
    from plantdreamer import _core

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
