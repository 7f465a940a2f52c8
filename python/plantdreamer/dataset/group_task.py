"""A packed group on a dataset worker: its plants trained together by one
`generate_group`, each in its own dataset folder, each with its own record; a plant's own
failure fails it alone (``packing.py`` makes the groups)."""

from __future__ import annotations

import io
import shutil
import time
import traceback
from contextlib import ExitStack, redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

from plantdreamer.dataset.tasks import (
    LOG_NAME,
    GuidanceFor,
    StepHook,
    chain_hooks,
    done_record,
    failed_record,
    folder_not_visible,
    hold_hook,
    resolved_config,
    set_threads,
    worker_info,
)
from plantdreamer.errors import InputError


def run_group(
    request: dict[str, Any], board: Any, guidance_for: GuidanceFor, on_step: StepHook | None
) -> dict[str, dict[str, Any]]:
    """Trains a packed group's plants together (``pipeline.group``), each in its own
    dataset folder; returns each plant's record. Plants with checkpoints resume; plants
    stopped at different steps (or fresh beside resumed ones) train as separate groups,
    one after another, so each continues exactly where it stopped."""
    from plantdreamer.pipeline.checkpoint import CHECKPOINT_NAME, load_checkpoint

    plants = request["plants"]
    threads = set_threads(request)
    info = worker_info()
    for plant in plants:
        board.started.remote(plant["id"], info)
    dirs = [Path(p["plant_dir"]) for p in plants]
    hidden = folder_not_visible(dirs[0], info)
    if hidden is not None:
        return {p["id"]: failed_record(info, hidden) for p in plants}
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
                     if (h := hold_hook(p["id"], d, tee)) is not None), None)  # fmt: skip
        for start, members in by_start.items():
            part = [plants[i] for i in members]
            first_saved = saved.get(members[0])
            results.update(
                _train_part(part, request["group_dir"], start, first_saved, info, guidance_for,
                            chain_hooks([on_step, hold]))
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
        guidance = guidance_for(resolved_config(cfgs[0], first_saved))
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
        failed = _failed_in(group_dir)  # before the stop: these stay failed
        return {
            i: failed_record(info, failed[i])
            if i in failed
            else {**info, "status": "interrupted", "error": error}
            for i in ids
        }
    except Exception as exc:  # the group could not start (models, settings): each plant fails
        traceback.print_exc()
        return {i: failed_record(info, f"{type(exc).__name__}: {exc}") for i in ids}
    out: dict[str, dict[str, Any]] = {}
    for p in part:
        if p["id"] in result.done:
            resumed = None if start is None or start < 0 else start
            record = done_record(info, t0, resumed, Path(p["plant_dir"]), result.done[p["id"]])
            out[p["id"]] = {**record, "trained_with": ids}
        else:
            out[p["id"]] = failed_record(info, result.failed.get(p["id"], "unknown error"))
    print(f"done: {len(result.done)} of {len(part)} plants in {time.perf_counter() - t0:.1f} s")
    return out


def _failed_in(group_dir: str) -> dict[str, str]:
    """The plants the group's record (written on every exit) says failed, with their error."""
    from plantdreamer.pipeline.group import failed_plants

    try:
        return failed_plants(Path(group_dir))
    except InputError:  # no record or a damaged one: nothing to keep failed
        return {}


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
