"""What a dataset run does with each plant, decided before any worker starts: skip it (a
``done`` record of the same config hash, its files there), resume it (same config: its
folder and checkpoint kept) or run it afresh (another config, or ``pending``: its folder
cleared first, after the record says ``pending``); and the units of work the workers get
(``packing.py``'s groups, less their finished plants)."""

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
from plantdreamer.errors import PlantDreamerError
from plantdreamer.exports.listing import PLANTS_DIR

# A plant's files that make it complete (with a `done` record of the same config).
COMPLETE_FILES = ("plant.ply", "run.json")
GROUPS_DIR = "groups"  # DIR/groups/<first plant>/group.json while a packed group trains


def plan(
    plants: list[Plant], manifest: Manifest, out_dir: Path, plants_per_gpu: int
) -> tuple[list[Plant], list[Plant]]:
    """The plants to run and the plants to skip, in spec order; stale folders cleared.

    ``plants_per_gpu`` is no part of the config hash: a finished plant is a valid plant
    whatever group made it (its record says which), so it is kept when B changes. An
    unfinished one started under another B starts again, so that its bytes are those of
    the group it is made in (an SDS plant's bytes depend on its group)."""
    todo, skipped = [], []
    for plant in plants:
        record = manifest.get(plant.id)
        folder = plant_dir(out_dir, plant)
        same_config = record is not None and record.get("config_hash") == plant.config_hash
        done = same_config and record is not None and record["status"] == "done"
        if done and all((folder / name).is_file() for name in COMPLETE_FILES):
            skipped.append(plant)
            continue
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
        if stale and (record is not None or folder.exists()):
            # The record changes first, so a stop while the files go never leaves a
            # `done` that has none.
            manifest.replace(plant.id, {**base_record(plant, plants_per_gpu), "status": "pending"})
            if folder.exists():
                shutil.rmtree(folder)
        todo.append(plant)
    return todo, skipped


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
