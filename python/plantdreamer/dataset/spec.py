"""A dataset spec: groups of plants (species or point-cloud files, seeds) and their options.

A spec is a TOML file::

    plants-per-gpu = 4      # plants trained together on one GPU (dataset.packing)

    [defaults]              # any `generate` setting, by its option name (`--points`: points)
    steps = 20
    guidance = "none"

    [[group]]
    species = "bean"
    seeds = "0-2"           # as `generate --seeds`: 0-7, 0,3,5 or both (or a list: [0, 7])

    [[group]]
    name = "scans"
    pointcloud = "scans/*.ply"    # a file or a glob, relative to the spec file
    species = "bean"              # names the plant in the prompts
    points = 50000

``growth`` (any group's, or [defaults]) may be a list or range of stages: a series of
each seed's plant at every stage, ids ending ``-g<stage>`` (``dataset.growth``).

A group's keys are spelled as `generate`'s and `dataset`'s options (``species``,
``pointcloud``, ``seeds``); the earlier ``pointclouds``, ``count`` and ``seed-start``
(``count = 3`` is ``seeds = "0-2"``) are still read, and refused beside their new name when
they name other plants.

Every plant becomes one ``GenerateConfig`` built like `generate`'s (``preset = "released"``
applies that preset under the spec's own settings), so any setting `generate` knows is
accepted and an unknown one is a clear error; every plant's config is checked (types,
ranges, species) here, before Ray starts.

A plant's folder name (its id) is made only of checked parts: the group ``name`` must be
letters, digits, ``-``, ``_`` and ``.`` (not first), and a point cloud's file name has any
other character replaced by ``_``. So a plant folder is always a direct child of
``OUT/plants``. A point cloud's config hash covers the file's contents (SHA-256), not only
its path: a scan replaced at the same path is run again.
"""

from __future__ import annotations

import glob
import re
import sys
from pathlib import Path
from typing import Any

from plantdreamer.dataset import packing
from plantdreamer.dataset.growth import growth_series
from plantdreamer.dataset.plant import Plant, config_hash
from plantdreamer.digests import file_digest
from plantdreamer.errors import InputError
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pipeline.settings.presets import resolve_config
from plantdreamer.seeds import parse_seeds, seed_range, seeds_text
from plantdreamer.settings import by_name, canonical

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

# Keys of a group that choose its plants; every other key is a generate setting.
# `pointclouds`, `count` and `seed-start` are earlier spellings of `pointcloud` and `seeds`.
_PLANT_KEYS = ("name", "species", "pointcloud", "seeds", "pointclouds", "count", "seed-start")
# A group name: a folder-name part that is never a path (no separator, no leading dot).
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,99}")
_UNSAFE_CHARACTERS = re.compile(r"[^A-Za-z0-9._-]")


def load_spec(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    try:
        spec = tomllib.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text (byte {exc.start}); TOML is UTF-8") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from None
    spec.setdefault("base_dir", str(path.resolve().parent))
    return spec


def with_settings(spec: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """The spec with ``overrides`` (the command line's settings) over its [defaults]."""
    defaults = _settings(spec.get("defaults", {}), "[defaults]")
    return {**spec, "defaults": {**defaults, **overrides}}


def expand(spec: dict[str, Any]) -> list[Plant]:
    """The plants of a spec, in spec order; ids are unique or this fails."""
    unknown = set(spec) - {"defaults", "group", "scene", "base_dir", *packing.spec_keys()}
    if unknown:
        raise InputError(
            f"spec: unknown sections {', '.join(sorted(unknown))} (use [defaults], [[group]] "
            f"and [[scene]], and {', '.join(sorted(by_name(packing.PackingConfig)))} at the top)"
        )
    defaults = _settings(spec.get("defaults", {}), "[defaults]")
    groups = spec.get("group", [])
    if not isinstance(groups, list) or not groups:
        raise InputError("spec: no plants; add at least one [[group]]")
    base_dir = Path(spec.get("base_dir", "."))
    plants: list[Plant] = []
    seen: dict[str, str] = {}
    digests: dict[Path, str] = {}
    for index, group in enumerate(groups, 1):
        for plant in _group_plants(group, index, defaults, base_dir, digests):
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


def _group_plants(
    group: Any, index: int, defaults: dict[str, Any], base_dir: Path, digests: dict[Path, str]
) -> list[Plant]:
    where = f"group {index}"
    table = _settings(group, where)
    name = _group_name(table.get("name", ""), where)
    if name:
        where = f"group {index} ({name})"
    settings = {**defaults, **{k: v for k, v in table.items() if k not in _PLANT_KEYS}}
    for key in ("pointcloud", "seed"):
        if key in settings:
            raise InputError(
                f"spec: {where}: {key!r} is chosen per group; give 'pointcloud' (a file or "
                "a glob) or 'seeds' in each [[group]]"
            )
    seeds = _seeds(table, where)
    # The group's own species, else the one of [defaults] or --set (every group's).
    species = table.get("species", settings.get("species"))
    pattern = _pointcloud(table, where)
    sources: list[tuple[str | None, str]]
    if pattern is not None:
        files = _glob(pattern, base_dir, where)
        sources = [(str(f), _UNSAFE_CHARACTERS.sub("_", f.stem).lstrip(".")) for f in files]
    elif species is not None:
        if not isinstance(species, str):
            raise InputError(f"spec: {where}: 'species' must be a string")
        sources = [(None, species)]
    else:
        raise InputError(f"spec: {where} needs 'species' or 'pointcloud'")
    stages = growth_series(settings, where)
    plants = []
    for pointcloud, stem in sources:
        digest = None
        if pointcloud is not None:
            path = Path(pointcloud)
            digest = digests.get(path) or digests.setdefault(path, file_digest(path))
        for seed in seeds:
            for stage in stages:
                data = {**settings, **stage.settings, "species": species,
                        "pointcloud": pointcloud, "seed": seed}  # fmt: skip
                try:
                    # A preset applies as on the command line: its values, then the spec's.
                    preset = data.pop("preset", GenerateConfig().preset)
                    cfg = resolve_config(str(preset), data)
                    cfg.validate()
                    _check_species(cfg)
                except (InputError, TypeError, ValueError) as exc:
                    raise InputError(f"spec: {where}: {exc}") from None
                plant_id = (
                    f"{name + '-' if name else ''}{stem or 'cloud'}-s{seed:04d}{stage.suffix}"
                )
                group_name = name or f"group{index}"
                plants.append(Plant(plant_id, group_name, cfg, config_hash(cfg, digest)))
    return plants


def _pointcloud(table: dict[str, Any], where: str) -> str | None:
    """The group's point clouds: ``pointcloud``, a file or a glob (relative to the spec
    file), or its earlier spelling ``pointclouds``; both given must be the same."""
    given = {key: table[key] for key in ("pointcloud", "pointclouds") if key in table}
    for key, value in given.items():
        if not isinstance(value, str):
            raise InputError(f"spec: {where}: {key!r} must be a file or glob pattern (a string)")
    if len(set(given.values())) > 1:
        raise InputError(
            f"spec: {where}: 'pointclouds' (the earlier spelling of 'pointcloud') gives "
            f"{given['pointclouds']!r} and 'pointcloud' {given['pointcloud']!r}; give "
            "'pointcloud' once"
        )
    return next(iter(given.values()), None)


def _group_name(name: Any, where: str) -> str:
    if not isinstance(name, str):
        raise InputError(f"spec: {where}: 'name' must be a string, got {name!r}")
    if name and not NAME_PATTERN.fullmatch(name):
        raise InputError(
            f"spec: {where}: group name {name!r} must be 1-100 letters, digits, '-', '_' or "
            "'.' (not first): it names the plants' folders, never a path"
        )
    return name


def _check_species(cfg: GenerateConfig) -> None:
    """An L-System species must exist (a point cloud's species only names it in prompts);
    a mistyped one is named with the closest known."""
    from plantdreamer.pipeline.settings.requested import check_species

    check_species(cfg)


def _seeds(table: dict[str, Any], where: str) -> list[int]:
    """The group's seeds: ``seeds`` in ``--seeds``' grammar (``"0-7,9"``) or a list, else
    the earlier ``count`` / ``seed-start``; both given must name the same seeds."""
    named = None
    if "seeds" in table:
        seeds = table["seeds"]
        if isinstance(seeds, str):
            named = parse_seeds(seeds, what=f"spec: {where}: 'seeds'")
        elif isinstance(seeds, list) and all(_is_int(s) for s in seeds):
            named = parse_seeds(",".join(map(str, seeds)), what=f"spec: {where}: 'seeds'")
        else:
            raise InputError(
                f"spec: {where}: 'seeds' must be ranges and numbers like \"0-7,9\" or a list "
                "of integers"
            )
    if named is None or "count" in table or "seed-start" in table:
        names = (f"spec: {where}: 'count'", "'seed-start'")
        counted = seed_range(table.get("count", 1), table.get("seed-start", 0), names)
        if named is not None and counted != named:
            raise InputError(
                f"spec: {where}: 'count' / 'seed-start' (the earlier spelling of 'seeds') name "
                f"seeds {seeds_text(counted)} and 'seeds' {seeds_text(named)}; give 'seeds' once"
            )
        named = counted
    return named


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)  # TOML's true is no count


def _glob(pattern: str, base_dir: Path, where: str) -> list[Path]:
    full = pattern if Path(pattern).is_absolute() else str(base_dir / pattern)
    files = sorted(Path(p).resolve() for p in glob.glob(full) if Path(p).is_file())
    if not files:
        raise InputError(f"spec: {where}: no files match {pattern!r} (in {base_dir})")
    stems = [f.stem for f in files]
    if len(set(stems)) != len(stems):
        raise InputError(f"spec: {where}: point clouds with the same file name in {pattern!r}")
    return files
