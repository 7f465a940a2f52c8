"""The record of a run of plants: one ``PlantEntry`` per plant (name, config, status,
folder), the same type for a plant alone, a group and a dataset unit. Where it is kept is
the layout's (``layout.py``): a group writes ``OUT/group.json``, a plant alone keeps it in
memory (its folder's checkpoint and run.json say the rest), a dataset unit reports it to
the dataset's manifest. Plain data and checks only (no torch): the command line and the
dataset driver read it without loading the trainer.

A plant's status is ``running``, ``done``, ``interrupted`` (at a step) or ``failed`` (with
its one-line error); a resume tries a failed plant again, whatever failed (a full disk
since freed, a file since fixed). A record read back is checked before anything is
written: a plant name is a plain folder name, at most ``MAX_GROUP_PLANTS`` plants, none
twice, and each plant's folder is ``OUT/<name>``.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plantdreamer import atomic
from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.pipeline.settings.config import GenerateConfig, check_shared
from plantdreamer.pipeline.settings.group_settings import check_group_size

GROUP_FILE = "group.json"
# A plant's folder name: never a path (no separator, no leading dot, not "..").
PLANT_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,99}")
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]")

RUNNING, DONE, FAILED, INTERRUPTED = "running", "done", "failed", "interrupted"


def plant_name(cfg: GenerateConfig) -> str:
    """``<species or point cloud file>-s<seed>``, made of folder-name characters only."""
    src = cfg.source
    stem = Path(src.pointcloud).stem if src.pointcloud is not None else str(src.species)
    return f"{_UNSAFE.sub('_', stem).lstrip('.') or 'plant'}-s{cfg.seed:04d}"


@dataclass
class PlantEntry:
    """One plant of a run: its name, settings, folder and where it stands."""

    name: str
    config: GenerateConfig
    folder: Path
    status: str = RUNNING  # RUNNING, DONE, FAILED or INTERRUPTED
    error: str | None = None  # FAILED: the one-line error
    stopped_at: int | None = None  # INTERRUPTED: the step its checkpoint holds

    def fail(self, exc: BaseException, plain: bool = False) -> str:
        """Records the plant's failure; returns the one line. ``plain``: the message is the
        error already (no type name before it)."""
        lines = str(exc).strip().splitlines() or [type(exc).__name__]
        line = lines[0] if plain else f"{type(exc).__name__}: {lines[0]}"
        self.status, self.error = FAILED, line
        return line

    def status_text(self) -> str:
        """The status as the record file writes it (``failed: <error>``, ``interrupted at
        step N``)."""
        if self.status == FAILED:
            return f"{FAILED}: {self.error}"
        if self.status == INTERRUPTED and self.stopped_at is not None:
            return f"{INTERRUPTED} at step {self.stopped_at}"
        return self.status


@dataclass
class RunRecord:
    """A run's plants, in their training order."""

    plants: list[PlantEntry] = field(default_factory=list)

    @classmethod
    def new(cls, cfgs: list[GenerateConfig], folders: list[Path], names: list[str]) -> RunRecord:
        """The record of new plants (every one ``running``): InputError unless they may
        train together (one trainer's size, shared settings, names apart)."""
        if not cfgs:
            raise InputError("a run needs at least one plant")
        check_group_size(len(cfgs))
        check_shared(cfgs)
        if len(set(names)) != len(names):
            raise InputError("two plants of the group have the same name (species or file, seed)")
        return cls([PlantEntry(n, c, f) for n, c, f in zip(names, cfgs, folders, strict=True)])

    def failed(self) -> dict[str, str]:
        """The plants that failed, with their one-line error."""
        return {p.name: p.error or "" for p in self.plants if p.status == FAILED}

    def write(self, out: Path) -> None:
        """``out/group.json`` (atomically)."""
        plants = [
            {"name": p.name, "config": p.config.to_dict(), "status": p.status_text()}
            for p in self.plants
        ]
        atomic.write_json(out / GROUP_FILE, {"plants": plants})

    @classmethod
    def read(cls, out: Path) -> RunRecord:
        """``out``'s record, checked (module docstring): a resume writes nowhere else."""
        where = out / GROUP_FILE
        try:
            data = json.loads(where.read_text())
            plants = data["plants"]
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
            _check_own_folder(where, out, entry)
        if len(set(names)) != len(names):
            raise InputError(f"{where}: a plant is listed twice")
        return cls([_entry(where, out, p) for p in plants])


def _check_own_folder(where: Path, out: Path, entry: dict[str, Any]) -> None:
    """A plant of a group record lives in ``out/<name>``: a plain name, no link, and a
    ``dir`` (written by earlier versions) that says so."""
    name = entry["name"]
    if not isinstance(name, str) or not PLANT_NAME.fullmatch(name):
        raise InputError(
            f"{where}: plant name {name!r} is not a plain folder name (letters, digits, "
            "-, _ and ., not first); a group's plants live in its own folder"
        )
    if ("dir" in entry and entry["dir"] != str(out / name)) or (out / name).is_symlink():
        raise InputError(
            f"{where}: plant {name} has its folder elsewhere "
            f"({entry.get('dir') or 'a link'}); a group's plants live in {out}/<name>"
        )


def _entry(where: Path, out: Path, saved: dict[str, Any]) -> PlantEntry:
    try:
        config = GenerateConfig.from_dict(saved["config"])
    except (PlantDreamerError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise InputError(f"{where}: damaged config of plant {saved['name']} ({exc})") from None
    entry = PlantEntry(saved["name"], config, out / saved["name"])
    text = saved["status"]
    if text.startswith(FAILED):
        entry.status, entry.error = FAILED, text.removeprefix(f"{FAILED}: ")
    elif text.startswith(INTERRUPTED):
        entry.status = INTERRUPTED
        found = re.fullmatch(r"interrupted at step (\d+)", text)
        entry.stopped_at = int(found.group(1)) if found else None
    elif text == DONE:
        entry.status = DONE
    return entry
