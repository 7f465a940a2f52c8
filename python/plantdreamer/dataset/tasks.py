"""What a dataset worker runs: one plant as one `generate`, or a packed group as one
`generate_group`, and the board workers report to.

These are plain functions and classes; the runner wraps them with ``ray.remote`` so this
module imports without Ray. Neither function raises for a plant's own errors: they come
back as a ``failed`` record with one line, and in a group a plant fails alone.
"""

from __future__ import annotations

import copy
import io
import os
import shutil
import socket
import time
import traceback
from collections.abc import Callable
from contextlib import ExitStack, redirect_stderr, redirect_stdout
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
    threads = _set_threads(request)
    info = worker_info()
    board.started.remote(plant_id, info)
    hidden = _folder_not_visible(plant_dir, info)
    if hidden is not None:
        return _failed(info, hidden)
    plant_dir.mkdir(parents=True, exist_ok=True)
    resume = (plant_dir / CHECKPOINT_NAME).is_file()
    t0 = time.perf_counter()
    with open(plant_dir / LOG_NAME, "a") as log, redirect_stdout(log), redirect_stderr(log):
        print(f"== plant {plant_id}, pid {info['pid']}, threads {threads}")
        on_steps = [on_step, _hold_hook(plant_id, plant_dir, log)]
        saved, resumed_from = None, None
        try:
            if resume:
                saved = load_checkpoint(plant_dir)
                resumed_from = int(saved["step"])
                print(f"resuming from the checkpoint at step {resumed_from}")
            cfg = GenerateConfig.from_dict(request["config"])
            guidance = guidance_for(_resolved(cfg, saved))
            # The plant folder is the dataset's (it holds this log): a fresh start replaces
            # whatever an earlier, incomplete attempt left there.
            result = generate(
                None if resume else cfg,
                plant_dir,
                guidance=guidance,
                resume=resume,
                overwrite=not resume,
                show_progress=True,
                on_step=_chain(on_steps),
            )
        except RunInterrupted as stop:
            return {**info, "status": "interrupted", "error": f"interrupted at step {stop.step}"}
        except Exception as exc:  # the plant's own failure: record it, keep the others going
            traceback.print_exc()
            return _failed(info, f"{type(exc).__name__}: {exc}")
        print(f"done: {result.gaussians} Gaussians in {time.perf_counter() - t0:.1f} s")
    return _done(info, t0, resumed_from, plant_dir, result)


def run_group(
    request: dict[str, Any], board: Any, guidance_for: GuidanceFor, on_step: StepHook | None
) -> dict[str, dict[str, Any]]:
    """Trains a packed group's plants together (``pipeline.group``), each in its own
    dataset folder; returns each plant's record. Plants with checkpoints resume; plants
    stopped at different steps (or fresh beside resumed ones) train as separate groups,
    one after another, so each continues exactly where it stopped."""
    from plantdreamer.pipeline.checkpoint import CHECKPOINT_NAME, load_checkpoint

    plants = request["plants"]
    threads = _set_threads(request)
    info = worker_info()
    for plant in plants:
        board.started.remote(plant["id"], info)
    dirs = [Path(p["plant_dir"]) for p in plants]
    hidden = _folder_not_visible(dirs[0], info)
    if hidden is not None:
        return {p["id"]: _failed(info, hidden) for p in plants}
    by_start: dict[int | None, list[int]] = {}
    saved: dict[int, dict[str, Any]] = {}
    for i, folder in enumerate(dirs):
        folder.mkdir(parents=True, exist_ok=True)
        start = None
        if (folder / CHECKPOINT_NAME).is_file():
            try:
                saved[i] = load_checkpoint(folder)
                start = int(saved[i]["step"])
            except Exception:  # damaged: the group's start fails this plant alone
                start = -1
        by_start.setdefault(start, []).append(i)
    results: dict[str, dict[str, Any]] = {}
    with ExitStack() as stack:
        logs = [stack.enter_context(open(d / LOG_NAME, "a")) for d in dirs]
        tee = _Tee(logs)
        stack.enter_context(redirect_stdout(tee))
        stack.enter_context(redirect_stderr(tee))
        ids = ", ".join(p["id"] for p in plants)
        print(f"== group of {len(plants)} ({ids}), pid {info['pid']}, threads {threads}")
        hold = next((h for p, d in zip(plants, dirs, strict=True)
                     if (h := _hold_hook(p["id"], d, tee)) is not None), None)  # fmt: skip
        for start, members in by_start.items():
            part = [plants[i] for i in members]
            first_saved = saved.get(members[0])
            results.update(
                _train_part(part, request["group_dir"], start, first_saved, info, guidance_for,
                            _chain([on_step, hold]))
            )  # fmt: skip
            if any(r["status"] == "interrupted" for r in results.values()):
                break
    stopped = {p["id"] for p in plants} - set(results)
    for plant_id in stopped:  # a stop came before this part of the group started
        results[plant_id] = {**info, "status": "interrupted", "error": "interrupted before start"}
    if not stopped and all(r["status"] != "interrupted" for r in results.values()):
        shutil.rmtree(request["group_dir"], ignore_errors=True)
    return results


def _train_part(
    part: list[dict[str, Any]],
    group_dir: str,
    start: int | None,
    first_saved: dict[str, Any] | None,
    info: dict[str, Any],
    guidance_for: GuidanceFor,
    on_step: StepHook | None,
) -> dict[str, dict[str, Any]]:
    from plantdreamer.pipeline import GenerateConfig, RunInterrupted
    from plantdreamer.pipeline.group import generate_group

    t0 = time.perf_counter()
    ids = [p["id"] for p in part]
    try:
        cfgs = [GenerateConfig.from_dict(p["config"]) for p in part]
        guidance = guidance_for(_resolved(cfgs[0], first_saved))
        if start is not None:
            print(f"resuming {', '.join(ids)} from their checkpoints at step {start}")
        result = generate_group(
            cfgs,
            group_dir,
            guidance=guidance,
            resume=start is not None,
            overwrite=True,
            show_progress=True,
            on_step=on_step,
            plant_dirs=[Path(p["plant_dir"]) for p in part],
        )
    except RunInterrupted as stop:
        error = f"interrupted at step {stop.step}"
        return {i: {**info, "status": "interrupted", "error": error} for i in ids}
    except Exception as exc:  # the group could not start (models, settings): each plant fails
        traceback.print_exc()
        return {i: _failed(info, f"{type(exc).__name__}: {exc}") for i in ids}
    out: dict[str, dict[str, Any]] = {}
    for p in part:
        if p["id"] in result.done:
            resumed = None if start is None or start < 0 else start
            record = _done(info, t0, resumed, Path(p["plant_dir"]), result.done[p["id"]])
            out[p["id"]] = {**record, "trained_with": ids}
        else:
            out[p["id"]] = _failed(info, result.failed.get(p["id"], "unknown error"))
    print(f"done: {len(result.done)} of {len(part)} plants in {time.perf_counter() - t0:.1f} s")
    return out


def _resolved(cfg: Any, saved: dict[str, Any] | None) -> Any:
    """The config the run will use (a checkpoint's, or ``cfg`` with the machine's choices
    filled), which decides the guidance."""
    from plantdreamer.pipeline import GenerateConfig
    from plantdreamer.pipeline.runtime import resolve_runtime

    if saved is not None:
        return GenerateConfig.from_dict(saved["config"])
    cfg = copy.deepcopy(cfg)
    resolve_runtime(cfg)
    return cfg


def _set_threads(request: dict[str, Any]) -> int:
    import torch

    threads = int(request["threads"])
    torch.set_num_threads(threads)
    return threads


def _folder_not_visible(plant_dir: Path, info: dict[str, Any]) -> str | None:
    from plantdreamer.dataset.lock import LOCK_NAME

    if plant_dir.parent.parent.joinpath(LOCK_NAME).exists():
        return None
    return (
        f"output folder {plant_dir.parent.parent} is not visible on this node "
        f"({info['host']}); a cluster needs it on a shared filesystem"
    )


def _done(info, t0, resumed_from, plant_dir: Path, result) -> dict[str, Any]:
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


def _failed(info: dict[str, Any], message: str) -> dict[str, Any]:
    lines = message.strip().splitlines() or ["unknown error"]
    return {**info, "status": "failed", "error": lines[0], "finished": time.time()}


def _gaussian_counts(plant_dir: Path, final: int) -> dict[str, int]:
    import json

    run = json.loads((plant_dir / "run.json").read_text())
    return {"initial": int(run["gaussians"]["initial"]), "final": final}


def _chain(hooks: list[StepHook | None]) -> StepHook | None:
    present = [h for h in hooks if h is not None]
    if not present:
        return None

    def each(step: int) -> None:
        for hook in present:
            hook(step)

    return each


class _Tee(io.TextIOBase):
    """A group's output, written to every plant's log."""

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


def _hold_hook(plant_id: str, plant_dir: Path, log: Any) -> StepHook | None:
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
