"""What a dataset run does with each plant, decided before any worker starts: skip it (a
``done`` record of the same config hash, its files there), resume it (same config: its
folder and checkpoint kept), make it (new, or started afresh: ``pending`` or another
config's unfinished run, its folder cleared first, after the record says ``pending``) or
redo it (a finished plant of other settings: deleted and made again, only when the run
asks for it with ``redo_changed``: a changed setting never silently throws away finished
plants); and the units of work the workers get (``packing.py``'s groups, less their
finished plants)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from plantdreamer.dataset.demand import Demand
from plantdreamer.dataset.manifest import Manifest
from plantdreamer.dataset.packing import pack
from plantdreamer.dataset.plant import Plant
from plantdreamer.dataset.scheduler import Unit
from plantdreamer.dataset.tasks import HELD_MARKER, LOG_NAME
from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.exports.listing import PLANTS_DIR
from plantdreamer.output_folder import remove_owned, survey
from plantdreamer.pipeline.state.run_outputs import COMPLETE_FILES, RUN_OUTPUTS, is_finished

ACTIONS = ("make", "resume", "skip", "redo")  # what a run does with a plant
# What a dataset writes in a plant folder (output_folder.Owned): a run's outputs, the log of
# its worker, the test hook's marker. Clearing a plant deletes these only.
PLANT_FILES = (*RUN_OUTPUTS, LOG_NAME, HELD_MARKER)


def plan(
    plants: list[Plant],
    manifest: Manifest,
    out_dir: Path,
    plants_per_gpu: int,
    redo_changed: bool = False,
) -> tuple[list[Plant], list[Plant]]:
    """The plants to run and the plants to skip, in spec order; stale folders cleared.

    Finished plants of other settings are refused (an InputError that counts them, before
    anything is deleted) unless ``redo_changed``. ``plants_per_gpu`` is no part of the
    config hash: a finished plant is a valid plant whatever group made it (its record says
    which), so it is kept when B changes. An unfinished one started under another B starts
    again, so that its bytes are those of the group it is made in (an SDS plant's bytes
    depend on its group)."""
    decided = [(plant, *decide(plant, manifest, out_dir, plants_per_gpu)) for plant in plants]
    redo = [plant for plant, action, _ in decided if action == "redo"]
    if redo and not redo_changed:
        shown = ", ".join(p.id for p in redo[:3]) + (", ..." if len(redo) > 3 else "")
        raise InputError(
            f"{len(redo)} finished plants in {out_dir} were made with other settings ({shown}); "
            "this run would delete and remake them: pass --redo-changed to do so, or write "
            "to another --out (--dry-run lists the plan)"
        )
    for plant, _, clear in decided:  # nothing cleared unless every folder is the plant's own
        if clear:
            survey(plant_dir(out_dir, plant), PLANT_FILES).refuse(plant_dir(out_dir, plant))
    todo, skipped = [], []
    for plant, action, clear in decided:
        if action == "skip":
            if manifest.get(plant.id) is None:  # found by its files: recorded again
                record = {**base_record(plant, plants_per_gpu), "status": "done"}
                manifest.replace(plant.id, record)
            skipped.append(plant)
            continue
        if clear:
            # The record changes first, so a stop while the files go never leaves a
            # `done` that has none.
            manifest.replace(plant.id, {**base_record(plant, plants_per_gpu), "status": "pending"})
            clear_plant_folder(plant_dir(out_dir, plant))
        todo.append(plant)
    return todo, skipped


def clear_plant_folder(folder: Path) -> None:
    """Deletes what the dataset wrote in a plant folder, then the folder once empty."""
    remove_owned(folder, PLANT_FILES)
    try:
        folder.rmdir()
    except FileNotFoundError:
        pass


def same_settings(folder: Path, plant: Plant) -> bool:
    """Whether a finished plant's run.json records ``plant``'s settings (those the run
    decided itself, left open in the plan, aside). A point cloud's contents are not in
    run.json: such a plant is never taken as the same without its record."""
    import json

    from plantdreamer.pipeline.settings.config import GenerateConfig

    if plant.config.source.pointcloud is not None:
        return False
    try:
        run = json.loads((folder / "run.json").read_text())
        recorded = GenerateConfig.from_dict(run["config"]).to_dict()
    except (OSError, ValueError, KeyError, TypeError, PlantDreamerError):
        return False
    wanted = plant.config.to_dict()
    return all(recorded.get(k) == v for k, v in wanted.items() if v not in (None, "auto"))


def decide(
    plant: Plant, manifest: Manifest, out_dir: Path, plants_per_gpu: int
) -> tuple[str, bool]:
    """What a run does with ``plant`` (one of ACTIONS) and whether its record and folder
    are cleared first; reads only. A finished plant without a record (its line deleted) is
    found by its own files: kept when its run.json has the plant's settings, else a redo."""
    record = manifest.get(plant.id)
    folder = plant_dir(out_dir, plant)
    if record is None and is_finished(folder):
        return ("skip", False) if same_settings(folder, plant) else ("redo", True)
    same_config = record is not None and record.get("config_hash") == plant.config_hash
    done = same_config and record is not None and record["status"] == "done"
    if done and all((folder / name).is_file() for name in COMPLETE_FILES):
        return "skip", False
    # Another config's record and files, a `pending` plant (no worker started it: its
    # folder holds only what a clearing cut short left), or a checkpoint of another B
    # (records older than this key resume as before).
    stale = not same_config or (
        record is not None
        and (
            record["status"] == "pending"
            or record.get("plants_per_gpu", plants_per_gpu) != plants_per_gpu
        )
    )
    clear = stale and (record is not None or folder.exists())
    if not same_config and record is not None and record.get("status") == "done":
        return "redo", clear
    if not stale and folder.is_dir():
        from plantdreamer.pipeline.state.checkpoint import (
            CHECKPOINT_NAME,  # torch: only when needed
        )

        if (folder / CHECKPOINT_NAME).is_file():
            return "resume", False
    return "make", clear


def check_models(plants: list[Plant]) -> None:
    """Every plant's LoRA, base model and ControlNet found (not loaded), before a plan is
    made or a folder cleared; each distinct set of models once (torch is imported only
    when there is one to look at)."""
    seen = set()
    for plant in plants:
        sds = plant.config.sds
        key = (sds.guidance, sds.lora, sds.base_model, sds.controlnet)
        if key in seen or (sds.guidance == "none" and sds.lora is None):
            continue
        seen.add(key)
        from plantdreamer.pipeline.settings.runtime import check_models as check

        check(plant.config)


def describe_plan(
    plants: list[Plant], manifest: Manifest, out_dir: Path, plants_per_gpu: int
) -> list[str]:
    """``--dry-run``'s lines: a count of each action, then each plant's action."""
    actions = [(plant, decide(plant, manifest, out_dir, plants_per_gpu)[0]) for plant in plants]
    counts = {a: sum(1 for _, b in actions if b == a) for a in ACTIONS}
    head = ", ".join(f"{counts[a]} {a}" for a in ACTIONS)
    lines = [f"plan for {len(plants)} plants in {out_dir}: {head}"]
    lines += [f"{action:<7} {plant.id}" for plant, action in actions]
    if counts["redo"]:
        lines.append("redo: finished plants of other settings; a run needs --redo-changed")
    return lines


def plant_dir(out_dir: Path, plant: Plant) -> Path:
    """``DIR/plants/<id>``, refused unless a direct child of ``DIR/plants``."""
    plants_dir = out_dir / PLANTS_DIR
    folder = plants_dir / plant.id
    # Ids are checked folder names; this keeps any other from reaching outside DIR.
    if folder.parent != plants_dir or folder.resolve().parent != plants_dir.resolve():
        raise PlantDreamerError(f"plant id {plant.id!r} is not a folder name in {plants_dir}")
    return folder


def base_record(plant: Plant, plants_per_gpu: int) -> dict[str, Any]:
    """A plant's manifest record before any worker reports on it; ``plants_per_gpu`` is
    the B of the run that makes it (a finished record adds ``trained_with``)."""
    folder = f"{PLANTS_DIR}/{plant.id}"
    return {
        "group": plant.group,
        "species": plant.species,
        "source": plant.source,
        "seed": plant.config.seed,
        "config_hash": plant.config_hash,
        "plants_per_gpu": plants_per_gpu,
        "plant_dir": folder,
        "log": f"{folder}/{LOG_NAME}",
    }


def work_units(
    plants: list[Plant],
    todo: list[Plant],
    demands: dict[str, Demand],
    out_dir: Path,
    plants_per_gpu: int,
) -> list[Unit]:
    """The packed groups' unfinished plants, in plan order (``packing.py``)."""
    wanted = {p.id for p in todo}
    units = []
    for group in pack(plants, plants_per_gpu):
        members = [p for p in group if p.id in wanted]
        if not members:
            continue
        demand = demands[members[0].id]
        request = {
            "plants": [
                {"id": p.id, "config": p.config.to_dict(), "plant_dir": str(plant_dir(out_dir, p))}
                for p in members
            ],
            "threads": demand.threads,
        }
        units.append(Unit(members, demand, request))
    return units
