"""Several plants trained together in one trainer: ``OUT/<species>-s<seed>/`` per plant.

The plants share every setting but their seed and point cloud (one guidance serves them
all: one batched network call per step, or one per half with ``overlap``), and keep their own cameras, optimiser, density
control, labels, checkpoint and outputs. ``OUT/group.json`` lists the plants and their
status (``running``, ``done`` or ``failed: <error>``); a plant that fails is recorded there
and the others go on. The same group (same plants, same order) gives the same bytes run
after run and after Ctrl-C + resume. The guidance's noise and timesteps come from one
generator (seeded by the first plant), so a plant made in a group is not the plant made
alone with SDS (docs/scaling.md).
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plantdreamer.errors import InputError
from plantdreamer.guidance.base import Guidance
from plantdreamer.output_folder import claim_folder
from plantdreamer.pipeline import outputs
from plantdreamer.pipeline.checkpoint import CHECKPOINT_NAME, load_checkpoint, restore_noise_state
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.export import RunResult, export_run
from plantdreamer.pipeline.run import RUN_OUTPUTS, remove_final_outputs, resumed_config
from plantdreamer.pipeline.run_state import RunState
from plantdreamer.pipeline.runtime import build_guidance, check_inputs, resolve_runtime
from plantdreamer.pipeline.trainer import PlantRun, Trainer

GROUP_FILE = "group.json"
PER_PLANT = ("seed", "pointcloud")  # the settings plants of one group may differ in


@dataclass
class GroupResult:
    out_dir: Path
    done: dict[str, RunResult] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)  # plant -> one-line error


def plant_name(cfg: GenerateConfig) -> str:
    src = cfg.source
    stem = Path(src.pointcloud).stem if src.pointcloud is not None else src.species
    return f"{stem}-s{cfg.seed:04d}"


def parse_seeds(text: str) -> list[int]:
    """``0-7``, ``0,3,5`` or both (``0-3,8``), in the order given; duplicates refused."""
    seeds: list[int] = []
    try:
        for part in (p.strip() for p in text.split(",") if p.strip()):
            low, dash, high = part.partition("-")
            seeds += list(range(int(low), int(high) + 1)) if dash else [int(part)]
    except ValueError:
        raise InputError(
            f"--seeds takes numbers and ranges like 0-7 or 0,3,5, got {text!r}"
        ) from None
    if not seeds or len(set(seeds)) != len(seeds):
        raise InputError(f"--seeds needs distinct seeds, got {text!r}")
    return seeds


def generate_group(
    cfgs: list[GenerateConfig] | None,
    out_dir: str | Path,
    *,
    guidance: Guidance | None = None,
    resume: bool = False,
    overwrite: bool = False,
    show_progress: bool = True,
    on_step: Callable[[int], None] | None = None,
    depth_ahead: bool = True,
    plant_dirs: list[Path] | None = None,
) -> GroupResult:
    """Trains ``cfgs`` together into ``out_dir`` (or, with ``resume``, continues the group
    there). ``guidance`` overrides the one the configs name (tests inject tiny models).
    ``plant_dirs`` puts the plants in these folders (named by them) rather than in
    ``out_dir``, which then holds only ``group.json`` (a dataset's plant folders); the
    record is then made from ``cfgs`` with or without ``resume``."""
    out = Path(out_dir)
    if resume and plant_dirs is None:
        record = _read_record(out)
    else:
        if not cfgs:
            raise InputError("a group needs at least one plant")
        record = _new_record(cfgs, plant_dirs)
    names = [p["name"] for p in record["plants"]]
    with claim_folder(out, overwrite=overwrite and not resume, owned=(GROUP_FILE, *names),
                      allow_existing=resume):  # fmt: skip
        result = GroupResult(out)
        try:
            with ExitStack() as stack:
                plants = _start(record, out, resume, result, stack, show_progress)
                outputs.write_json(out / GROUP_FILE, record)
                if plants:
                    _train(
                        plants, record, out, guidance, result, show_progress, on_step, depth_ahead
                    )
        finally:  # also on Ctrl-C: a plant failed before the stop stays failed on resume
            outputs.write_json(out / GROUP_FILE, record)
        for entry in record["plants"]:
            if entry["status"] == "done" and entry["name"] not in result.done:
                plant_dir = Path(entry.get("dir", out / entry["name"]))
                run = json.loads((plant_dir / "run.json").read_text())
                ply = plant_dir / "plant.ply"
                result.done[entry["name"]] = RunResult(
                    plant_dir, ply, run["config"]["train"]["steps"],
                    run["gaussians"]["final"], run["timings_s"],
                )  # fmt: skip
        return result


def _new_record(cfgs: list[GenerateConfig], dirs: list[Path] | None) -> dict[str, Any]:
    shared = [{k: v for k, v in c.settings().items() if k not in PER_PLANT} for c in cfgs]
    if any(s != shared[0] for s in shared[1:]):
        differ = sorted({k for s in shared[1:] for k in s if s[k] != shared[0][k]})
        raise InputError(
            f"plants of one group share every setting but {' and '.join(PER_PLANT)}; "
            f"these differ: {', '.join(differ)}"
        )
    names = [plant_name(c) for c in cfgs] if dirs is None else [d.name for d in dirs]
    if len(set(names)) != len(names):
        raise InputError("two plants of the group have the same name (species or file, seed)")
    plants = [
        {"name": n, "config": c.to_dict(), "status": "running"}
        for n, c in zip(names, cfgs, strict=True)
    ]
    for entry, folder in zip(plants, dirs or [], strict=False):
        entry["dir"] = str(folder)
    return {"plants": plants}


def _read_record(out: Path) -> dict[str, Any]:
    try:
        record = json.loads((out / GROUP_FILE).read_text())
        assert all({"name", "config", "status"} <= set(p) for p in record["plants"])
    except FileNotFoundError:
        raise InputError(f"{out} holds no group of plants ({GROUP_FILE} missing)") from None
    except (ValueError, KeyError, TypeError, AssertionError) as exc:
        raise InputError(f"{out / GROUP_FILE}: damaged ({exc})") from None
    return record


def failed_plants(out: Path) -> dict[str, str]:
    """The plants ``out``'s group record says failed, with their one-line error."""
    return _failed(_read_record(out))


def _failed(record: dict[str, Any]) -> dict[str, str]:
    return {
        p["name"]: p["status"].removeprefix("failed: ")
        for p in record["plants"]
        if p["status"].startswith("failed")
    }


def _start(record, out, resume, result, stack, show_progress) -> list[tuple[PlantRun, Any]]:
    """Each plant not done or failed, fresh or from its checkpoint; a plant that cannot
    start (bad input, damaged checkpoint) is failed alone."""
    plants = []
    result.failed.update(_failed(record))
    for entry in record["plants"]:
        if entry["status"] != "running":
            continue
        plant_dir = Path(entry.get("dir", out / entry["name"]))
        try:
            stack.enter_context(
                claim_folder(plant_dir, overwrite=not resume, owned=RUN_OUTPUTS,
                             allow_existing=resume)
            )  # fmt: skip
            if resume:
                saved = load_checkpoint(plant_dir)
                cfg, _ = resumed_config(saved, {}, plant_dir)
                check_inputs(cfg)
                remove_final_outputs(plant_dir)
            else:
                saved, cfg = None, GenerateConfig.from_dict(entry["config"])
                check_inputs(cfg)
            cfg = copy.deepcopy(cfg)
            resolve_runtime(cfg)
            resolution = cfg.train.resolution
            assert resolution is not None
            if saved is None:
                state = RunState.fresh(cfg, resolution, show_progress)
            else:
                state = RunState.resumed(cfg, resolution, saved)
                state.events.append({"step": state.step, "event": "resumed in a group"})
            plants.append((PlantRun(cfg, state, plant_dir), saved))
        except Exception as exc:  # this plant's own failure: the others go on
            _fail(entry, result, exc)
    return plants


def _train(started, record, out, guidance, result, show_progress, on_step, depth_ahead) -> None:
    entries = {Path(e.get("dir", out / e["name"])): e for e in record["plants"]}
    plants, saved = [p for p, _ in started], started[0][1]
    guidance = guidance if guidance is not None else build_guidance(plants[0].cfg)
    if saved is not None:
        restore_noise_state(guidance.generator, saved, plants[0].out_dir / CHECKPOINT_NAME)
    trainer = Trainer(plants, guidance, depth_ahead=depth_ahead, isolate_failures=True,
                      out_dir=out)  # fmt: skip
    try:
        trainer.run(show_progress, on_step)
    finally:  # the plants that failed in training, recorded however the run ends
        for p in plants:
            if p.error is not None:
                _fail(entries[p.out_dir], result, PlantDreamerFailure(p.error))
    device = str(getattr(guidance, "device", "cpu"))
    for p in plants:
        entry = entries[p.out_dir]
        if p.error is not None:
            continue
        try:
            resolution = p.cfg.train.resolution
            assert resolution is not None
            result.done[entry["name"]] = export_run(
                p.cfg, p.state, p.out_dir, resolution, device, show_progress
            )
            entry["status"] = "done"
        except Exception as exc:
            _fail(entry, result, exc)


class PlantDreamerFailure(Exception):
    """A plant's failure recorded by the trainer (its message is the error)."""


def _fail(entry: dict[str, Any], result: GroupResult, exc: BaseException) -> None:
    lines = str(exc).strip().splitlines() or [type(exc).__name__]
    what = "" if isinstance(exc, PlantDreamerFailure) else f"{type(exc).__name__}: "
    entry["status"] = f"failed: {what}{lines[0]}"
    result.failed[entry["name"]] = f"{what}{lines[0]}"
