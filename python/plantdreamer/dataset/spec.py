"""A dataset spec: groups of plants (species or point-cloud files, seeds) and their options.

A spec is a TOML file::

    [defaults]              # any `generate` setting, by its option name (`--points`: points)
    steps = 20
    guidance = "none"

    [[group]]
    species = "bean"
    count = 3               # seeds seed-start .. seed-start + count - 1 (or: seeds = [0, 7])

    [[group]]
    name = "scans"
    pointclouds = "scans/*.ply"   # a glob, relative to the spec file
    species = "bean"              # names the plant in the prompts
    points = 50000

Every plant becomes one ``GenerateConfig`` built like `generate`'s (``preset = "released"``
applies that preset under the spec's own settings), so any setting `generate` knows is
accepted and an unknown one is a clear error.
"""

from __future__ import annotations

import glob
import hashlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from plantdreamer.errors import InputError
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.presets import resolve_config
from plantdreamer.settings import canonical

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

# Keys of a group that choose its plants; every other key is a generate setting.
_PLANT_KEYS = ("name", "species", "pointclouds", "seeds", "count", "seed-start")


@dataclass(frozen=True)
class Plant:
    """One plant of the dataset: its folder name and the full config of its run."""

    id: str
    group: str
    config: GenerateConfig
    config_hash: str

    @property
    def species(self) -> str | None:
        return self.config.source.species

    @property
    def source(self) -> str:
        return self.config.source.pointcloud or "lsystem"


def config_hash(cfg: GenerateConfig) -> str:
    """A stable hash of every setting (sorted JSON), to tell whether a plant is up to date."""
    text = json.dumps(cfg.to_dict(), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def load_spec(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    try:
        spec = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from exc
    spec.setdefault("base_dir", str(path.resolve().parent))
    return spec


def expand(spec: dict[str, Any]) -> list[Plant]:
    """The plants of a spec, in spec order; ids are unique or this fails."""
    unknown = set(spec) - {"defaults", "group", "base_dir"}
    if unknown:
        raise InputError(
            f"spec: unknown sections {', '.join(sorted(unknown))} (use [defaults] and [[group]])"
        )
    defaults = _settings(spec.get("defaults", {}), "[defaults]")
    groups = spec.get("group", [])
    if not isinstance(groups, list) or not groups:
        raise InputError("spec: no plants; add at least one [[group]]")
    base_dir = Path(spec.get("base_dir", "."))
    plants: list[Plant] = []
    seen: dict[str, str] = {}
    for index, group in enumerate(groups, 1):
        for plant in _group_plants(group, index, defaults, base_dir):
            if plant.id in seen:
                raise InputError(
                    f"spec: plant id {plant.id!r} appears twice ({seen[plant.id]} and "
                    f"{plant.group}); give the groups different names"
                )
            seen[plant.id] = plant.group
            plants.append(plant)
    return plants


def _settings(table: Any, where: str) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise InputError(f"spec: {where} must be a table of generate settings")
    # Keys are setting names as on the command line; TOML users may write `_` for `-`.
    return {canonical(key): value for key, value in table.items()}


def _group_plants(group: Any, index: int, defaults: dict[str, Any], base_dir: Path) -> list[Plant]:
    where = f"group {index}"
    table = _settings(group, where)
    name = str(table.get("name", ""))
    if name:
        where = f"group {index} ({name})"
    settings = {**defaults, **{k: v for k, v in table.items() if k not in _PLANT_KEYS}}
    for key in ("pointcloud", "seed"):
        if key in settings:
            raise InputError(
                f"spec: {where}: {key!r} is chosen per plant; use 'pointclouds' (a glob) "
                "or 'seeds' / 'count' in the group"
            )
    seeds = _seeds(table, where)
    species = table.get("species")
    sources: list[tuple[str | None, str]]
    if "pointclouds" in table:
        files = _glob(str(table["pointclouds"]), base_dir, where)
        sources = [(str(f), f.stem) for f in files]
    elif species is not None:
        sources = [(None, str(species))]
    else:
        raise InputError(f"spec: {where} needs 'species' or 'pointclouds'")
    plants = []
    for pointcloud, stem in sources:
        for seed in seeds:
            data = {**settings, "species": species, "pointcloud": pointcloud, "seed": seed}
            try:
                # A preset applies as on the command line: its values, then the spec's own.
                preset = data.pop("preset", GenerateConfig().preset)
                cfg = resolve_config(str(preset), data)
                cfg.validate()
            except (InputError, TypeError, ValueError) as exc:
                raise InputError(f"spec: {where}: {exc}") from None
            plant_id = f"{name + '-' if name else ''}{stem}-s{seed:04d}"
            plants.append(Plant(plant_id, name or f"group{index}", cfg, config_hash(cfg)))
    return plants


def _seeds(table: dict[str, Any], where: str) -> list[int]:
    if "seeds" in table and "count" in table:
        raise InputError(f"spec: {where}: give 'seeds' or 'count', not both")
    if "seeds" in table:
        seeds = table["seeds"]
        if not isinstance(seeds, list) or not all(isinstance(s, int) for s in seeds):
            raise InputError(f"spec: {where}: 'seeds' must be a list of integers")
        if len(set(seeds)) != len(seeds):
            raise InputError(f"spec: {where}: 'seeds' has duplicates")
        return list(seeds)
    count, start = table.get("count", 1), table.get("seed-start", 0)
    if not isinstance(count, int) or count < 1 or not isinstance(start, int) or start < 0:
        raise InputError(f"spec: {where}: 'count' must be >= 1 and 'seed-start' >= 0")
    return list(range(start, start + count))


def _glob(pattern: str, base_dir: Path, where: str) -> list[Path]:
    full = pattern if Path(pattern).is_absolute() else str(base_dir / pattern)
    files = sorted(Path(p).resolve() for p in glob.glob(full) if Path(p).is_file())
    if not files:
        raise InputError(f"spec: {where}: no files match {pattern!r} (in {base_dir})")
    stems = [f.stem for f in files]
    if len(set(stems)) != len(stems):
        raise InputError(f"spec: {where}: point clouds with the same file name in {pattern!r}")
    return files
