"""A group's record, ``OUT/group.json``: its plants (name, config, status), the settings
they may differ in and the largest group. Plain data and checks only (no torch), so the
command line and ``dataset/packing.py`` read it without loading the trainer.

A plant's status is ``running``, ``done``, ``interrupted at step N`` or ``failed: <error>``
(a resume tries a failed plant again, whatever failed: a full disk since freed, a file
since fixed). A record read back for a resume is checked before anything is written: a plant name is a plain
folder name, and a plant's folder is ``OUT/<name>`` unless the caller gives the folders.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from plantdreamer.errors import InputError

if TYPE_CHECKING:
    from plantdreamer.pipeline.config import GenerateConfig

GROUP_FILE = "group.json"
PER_PLANT = ("seed", "pointcloud")  # the settings plants of one group may differ in
# The most plants one trainer holds (each keeps its model, optimiser and renders in memory
# from step 0); dataset's --plants-per-gpu has the same limit.
MAX_GROUP_PLANTS = 64
# A plant's folder name: never a path (no separator, no leading dot, not ".." ).
PLANT_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,99}")
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]")


def plant_name(cfg: GenerateConfig) -> str:
    """``<species or point cloud file>-s<seed>``, made of folder-name characters only."""
    src = cfg.source
    stem = Path(src.pointcloud).stem if src.pointcloud is not None else str(src.species)
    return f"{_UNSAFE.sub('_', stem).lstrip('.') or 'plant'}-s{cfg.seed:04d}"


def check_group_size(plants: int, what: str = "a group") -> None:
    if plants > MAX_GROUP_PLANTS:
        raise InputError(
            f"{what} of {plants} plants is more than one trainer holds (at most "
            f"{MAX_GROUP_PLANTS}, as --plants-per-gpu); train them as several groups, or "
            "with `plantdreamer dataset`"
        )


def check_shared(cfgs: Sequence[GenerateConfig]) -> None:
    """InputError unless the plants share every setting but the ``PER_PLANT`` ones."""
    shared = [{k: v for k, v in c.settings().items() if k not in PER_PLANT} for c in cfgs]
    if any(s != shared[0] for s in shared[1:]):
        differ = sorted({k for s in shared[1:] for k in s if s[k] != shared[0][k]})
        raise InputError(
            f"plants of one group share every setting but {' and '.join(PER_PLANT)}; "
            f"these differ: {', '.join(differ)}"
        )


def new_record(cfgs: list[GenerateConfig], dirs: list[Path] | None) -> dict[str, Any]:
    """The record of a new group (every plant ``running``); ``dirs``: the plants' folders,
    named by them (a dataset's), else ``OUT/<plant_name>``."""
    if not cfgs:
        raise InputError("a group needs at least one plant")
    check_group_size(len(cfgs))
    check_shared(cfgs)
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


def read_record(out: Path, own_folders: bool = True) -> dict[str, Any]:
    """``out``'s record, checked: every plant a plain name, at most ``MAX_GROUP_PLANTS``, no
    name twice, and with ``own_folders`` its folder ``out/<name>`` (``dir``, if given, says
    so) and no link: a resume writes nowhere else."""
    where = out / GROUP_FILE
    try:
        record = json.loads(where.read_text())
        plants = record["plants"]
        assert isinstance(plants, list) and plants, "no plants"
        assert all(isinstance(p, dict) and {"name", "config", "status"} <= set(p)
                   and isinstance(p["status"], str) for p in plants), "a plant's entry"  # fmt: skip
    except FileNotFoundError:
        raise InputError(f"{out} holds no group of plants ({GROUP_FILE} missing)") from None
    except (ValueError, KeyError, TypeError, AssertionError) as exc:
        raise InputError(f"{where}: damaged ({exc})") from None
    check_group_size(len(plants), f"{where}: a group")
    names = [p["name"] for p in plants]
    for entry in plants:
        name = entry["name"]
        if not isinstance(name, str) or not PLANT_NAME.fullmatch(name):
            raise InputError(
                f"{where}: plant name {name!r} is not a plain folder name (letters, digits, "
                "-, _ and ., not first); a group's plants live in its own folder"
            )
        if not own_folders:
            continue
        if ("dir" in entry and entry["dir"] != str(out / name)) or (out / name).is_symlink():
            raise InputError(
                f"{where}: plant {name} has its folder elsewhere "
                f"({entry.get('dir') or 'a link'}); a group's plants live in {out}/<name>"
            )
    if len(set(names)) != len(names):
        raise InputError(f"{where}: a plant is listed twice")
    return record


def plant_dir(out: Path, entry: dict[str, Any]) -> Path:
    return Path(entry["dir"]) if "dir" in entry else out / entry["name"]


def failed(record: dict[str, Any]) -> dict[str, str]:
    """The plants the record says failed, with their one-line error."""
    return {
        p["name"]: p["status"].removeprefix("failed: ")
        for p in record["plants"]
        if p["status"].startswith("failed")
    }


def failed_plants(out: Path) -> dict[str, str]:
    """The plants ``out``'s group record says failed, with their one-line error."""
    return failed(read_record(out, own_folders=False))


def mark_failed(entry: dict[str, Any], exc: BaseException, plain: bool = False) -> str:
    """Records a plant's failure in its entry; the one line is also returned. ``plain``:
    the message is already the error (no type name before it)."""
    lines = str(exc).strip().splitlines() or [type(exc).__name__]
    line = lines[0] if plain else f"{type(exc).__name__}: {lines[0]}"
    entry["status"] = f"failed: {line}"
    return line
