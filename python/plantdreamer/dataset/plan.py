"""What a dataset run does with each plant, decided before any worker starts: skip it (a
``done`` record of the same config hash, its files there), resume it (same config: its
folder and checkpoint kept), make it (new, or started afresh: ``pending`` or another
config's unfinished run, its folder cleared first, after the record says ``pending``) or
redo it (a finished plant of other settings: deleted and made again, only when the run
asks for it with ``redo_changed``: a changed setting never silently throws away finished
plants); and the units of work the workers get (``packing.py``'s groups, less their
finished plants)."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from plantdreamer.dataset.engine import Demand
from plantdreamer.dataset.manifest import Manifest
from plantdreamer.dataset.packing import pack
from plantdreamer.dataset.plant import Plant
from plantdreamer.dataset.scheduler import Unit
from plantdreamer.dataset.tasks import LOG_NAME
from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.exports.listing import PLANTS_DIR

# A plant's files that make it complete (with a `done` record of the same config).
COMPLETE_FILES = ("plant.ply", "run.json")
GROUPS_DIR = "groups"  # DIR/groups/<first plant>/group.json while a packed group trains
ACTIONS = ("make", "resume", "skip", "redo")  # what a run does with a plant


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
    todo, skipped = [], []
    for plant, action, clear in decided:
        if action == "skip":
            skipped.append(plant)
            continue
        if clear:
            # The record changes first, so a stop while the files go never leaves a
            # `done` that has none.
            manifest.replace(plant.id, {**base_record(plant, plants_per_gpu), "status": "pending"})
            folder = plant_dir(out_dir, plant)
            if folder.exists():
                shutil.rmtree(folder)
        todo.append(plant)
    return todo, skipped


def decide(
    plant: Plant, manifest: Manifest, out_dir: Path, plants_per_gpu: int
) -> tuple[str, bool]:
    """What a run does with ``plant`` (one of ACTIONS) and whether its record and folder
    are cleared first; reads only."""
    record = manifest.get(plant.id)
    folder = plant_dir(out_dir, plant)
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
        from plantdreamer.pipeline.checkpoint import CHECKPOINT_NAME  # torch: only when needed

        if (folder / CHECKPOINT_NAME).is_file():
            return "resume", False
    return "make", clear


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
            # group.json of a group in training; named by the packed group's first plant
            "group_dir": str(out_dir / GROUPS_DIR / group[0].id),
        }
        units.append(Unit(members, demand, request))
    return units
