"""A dataset request, whichever front end gave it: ``plantdreamer dataset`` and
``plantdreamer.make_dataset`` both call ``dataset_request``, which turns what was given
(a spec file or table, or species / point clouds and seeds; settings for every plant; the
run's and the label files' options) into the spec, its plants and the run's options, each
checked before anything is written, imported heavily or started: the spec and every
plant's settings and species, the device on this machine, the models and LoRA, the
packing, the resources, and every option's type and limits (``OPTION_LIMITS``, which the
command line's parser applies too: a Python caller's ``overwrite="no"`` or
``max_retries=-1`` is refused as the command line refuses it, never read by truthiness).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from plantdreamer.dataset.demand import custom_resources
from plantdreamer.dataset.packing import packing_from
from plantdreamer.dataset.plant import Plant
from plantdreamer.dataset.runner import RunOptions
from plantdreamer.dataset.scenes import expand_scenes, with_scene_table
from plantdreamer.dataset.spec import expand, load_spec, with_settings
from plantdreamer.errors import InputError
from plantdreamer.settings import canonical

# Each number option's kind and least value: the command line's types (click.IntRange)
# and the API's checks read them here.
OPTION_LIMITS: dict[str, tuple[type, float]] = {
    "local_cpus": (int, 1),
    "max_retries": (int, 0),
    "split_seed": (int, 0),
    "min_instance_area": (int, 1),
    "cpus_per_plant": (float, 1),
    "gpus_per_plant": (float, 0),
}
DEFAULT_MAX_RETRIES = 3  # re-runs of a plant whose worker died


@dataclass(frozen=True)
class DatasetRequest:
    spec: dict[str, Any]
    plants: list[Plant]
    options: RunOptions


def dataset_request(
    *,
    spec: str | Path | Mapping[str, Any] | None = None,
    species: str | Iterable[str] | None = None,
    pointcloud: str | Path | None = None,
    seeds: str | Iterable[int] | None = None,
    count: int | None = None,
    seed_start: int | None = None,
    settings: Mapping[str, Any] | None = None,
    plants_per_gpu: int | None = None,
    scenes: str | Iterable[int] | None = None,
    scene_settings: Mapping[str, Any] | None = None,
    address: str | None = None,
    local_cpus: int | None = None,
    cpus_per_plant: float | None = None,
    gpus_per_plant: float | None = None,
    resources: Mapping[str, Any] | None = None,
    max_retries: int | None = None,
    split: str | Iterable[float] | None = None,
    split_seed: int | None = None,
    split_mode: str | None = None,
    stuff: str | Iterable[str] | None = None,
    allow_empty_split: bool | None = None,
    min_instance_area: int | None = None,
    redo_changed: bool = False,
    show_progress: bool = True,
) -> DatasetRequest:
    """The request's spec, plants, scenes and options, checked (see the module docstring).
    ``scenes``: seeds of scenes of the finished plants (``dataset --scenes``), with
    ``scene_settings`` (scene-plants, scene-layout, scene-spacing; None: each default); a
    spec's ``[[scene]]`` tables make them too.
    ``spec``: a TOML file, or the same as a table (paths in it relative to the working
    folder); ``count`` / ``seed_start``: the earlier spelling of ``seeds`` (the command
    line's hidden ``--count`` / ``--seed-start``). None leaves an option at its default."""
    numbers = {"local_cpus": local_cpus, "max_retries": max_retries, "split_seed": split_seed,
               "min_instance_area": min_instance_area, "cpus_per_plant": cpus_per_plant,
               "gpus_per_plant": gpus_per_plant}  # fmt: skip
    for name, value in numbers.items():
        check_number(name, value)
    for name, flag in (("allow_empty_split", allow_empty_split), ("redo_changed", redo_changed),
                       ("show_progress", show_progress)):  # fmt: skip
        check_flag(name, flag)
    if address is not None and not isinstance(address, str):
        raise InputError(f"address must be text (auto, local or HOST:PORT), got {address!r}")
    table = spec_table(spec, species, pointcloud, seeds, count, seed_start)
    packing = packing_from(table, {"plants-per-gpu": plants_per_gpu})
    overrides = {canonical(str(k)): v for k, v in (settings or {}).items()}
    _one_species(table, overrides)
    table = with_settings(table, overrides)
    plants = expand(table)  # every plant's settings and species checked here
    scene_text = scenes if scenes is None or isinstance(scenes, str) else ",".join(map(str, scenes))
    table = with_scene_table(table, scene_text, dict(scene_settings or {}))
    scene_plans = expand_scenes(table)  # and every scene's settings
    check_plants(plants, device_here=address is None or address == "local")
    labels = label_options(
        split, split_seed, min_instance_area, allow_empty_split, stuff, split_mode
    )
    options = RunOptions(
        address=address,
        local_cpus=local_cpus,
        cpus_per_plant=cpus_per_plant,
        gpus_per_plant=gpus_per_plant,
        resources=custom_resources(_resource_texts(resources)),
        max_retries=DEFAULT_MAX_RETRIES if max_retries is None else max_retries,
        plants_per_gpu=packing.plants_per_gpu,
        show_progress=show_progress,
        labels=labels,
        redo_changed=redo_changed,
        scenes=scene_plans,
    )
    return DatasetRequest(table, plants, options)


def check_flag(name: str, value: Any) -> None:
    """A flag is True or False (the command line's flags cannot be anything else, so the
    message names the API's keyword)."""
    if value is not None and not isinstance(value, bool):
        raise InputError(f"{name} must be True or False, got {value!r}")


def check_number(name: str, value: Any) -> None:
    """``value`` (None: the default) of the kind and at least the least value that
    ``OPTION_LIMITS`` gives ``name``; a bool is no number, a float no count. The message
    names the option (``--cpus-per-plant``; the API says ``cpus_per_plant``)."""
    if value is None:
        return
    kind, least = OPTION_LIMITS[name]
    option = "--" + name.replace("_", "-")
    integral = isinstance(value, int) and not isinstance(value, bool)
    real = integral or isinstance(value, float)
    if (kind is int and not integral) or not real:
        what = "an integer" if kind is int else "a number"
        raise InputError(f"{option} must be {what} >= {least:g}, got {value!r}")
    if not (math.isfinite(value) and value >= least):
        raise InputError(f"{option} must be >= {least:g}, got {value!r}")


def check_plants(plants: list[Plant], device_here: bool) -> None:
    """Every plant's device on this machine (``device_here``: it runs here) and the models
    and LoRA each distinct set names, found, before anything starts."""
    from plantdreamer.dataset.plan import check_models
    from plantdreamer.devices import check_device

    if device_here:
        for device in {p.config.sds.device for p in plants}:
            check_device(device)
    check_models(plants)


def spec_table(
    spec: str | Path | Mapping[str, Any] | None,
    species: str | Iterable[str] | None,
    pointcloud: str | Path | None,
    seeds: str | Iterable[int] | None,
    count: int | None = None,
    seed_start: int | None = None,
) -> dict[str, Any]:
    """The spec file or table, or the one that species / point clouds and seeds describe
    (a group per species, each with those seeds)."""
    from plantdreamer.pipeline.settings.requested import seeds_of
    from plantdreamer.seeds import seed_range, seeds_text

    names = _names(species)
    if spec is not None:
        given = [name for name, value in (("--species", names), ("--pointcloud", pointcloud),
                 ("--seeds", seeds), ("--count", count), ("--seed-start", seed_start))
                 if value]  # fmt: skip
        if given:
            raise InputError(f"give a spec or {', '.join(given)}, not both")
        if isinstance(spec, Mapping):
            return {"base_dir": str(Path.cwd()), **spec}
        if not isinstance(spec, (str, Path)):
            raise InputError(f"spec must be a TOML file or a table, got {spec!r}")
        return load_spec(spec)
    chosen = seeds_of(seeds) if seeds is not None else None
    if count is not None or seed_start is not None or chosen is None:
        counted = seed_range(1 if count is None else count, 0 if seed_start is None else seed_start)
        if chosen is not None and counted != chosen:  # the earlier spelling beside the new
            raise InputError(
                f"--count / --seed-start (the earlier name of --seeds) gives "
                f"{seeds_text(counted)} and --seeds gives {seeds_text(chosen)}; give --seeds once"
            )
        chosen = counted
    if pointcloud is not None:
        if not isinstance(pointcloud, (str, Path)):
            raise InputError(f"pointcloud must be a file or a glob, got {pointcloud!r}")
        if len(names) > 1:
            raise InputError("--pointcloud names its plant with one --species, not several")
        group = {"pointcloud": str(Path(pointcloud).resolve()), "seeds": chosen}
        return {"group": [{**group, "species": name} for name in names] or [group]}
    if not names:
        raise InputError("give a spec, --species or --pointcloud")
    return {"group": [{"species": name, "seeds": chosen} for name in names]}


def label_options(
    split: str | Iterable[float] | None,
    split_seed: int | None,
    min_instance_area: int | None,
    allow_empty_split: bool | None,
    stuff: str | Iterable[str] | None,
    split_mode: str | None = None,
) -> Any:
    """The ``LabelOptions`` of the options given (None: each at its default): ``split`` as
    ``"0.8,0.1,0.1"`` or three non-negative numbers, normalised to shares either way;
    ``stuff`` as ``"pot,soil"`` or names; ``split_mode`` one of ``exports.splits.SPLIT_MODES`` (``LabelOptions`` checks it)."""
    from plantdreamer.exports.dataset import LabelOptions
    from plantdreamer.exports.splits import parse_ratios

    given: dict[str, Any] = {}
    if split is not None:
        if not isinstance(split, str):  # three numbers: the same rule as their text
            values = list(split) if isinstance(split, Iterable) else [split]
            numbers = [v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)]
            if len(numbers) != len(values) or not all(math.isfinite(v) and v >= 0 for v in numbers):
                raise InputError(
                    f"--split must be TRAIN,VAL,TEST (three non-negative numbers), got {split!r}"
                )
            split = ",".join(repr(float(v)) for v in values)
        given["ratios"] = parse_ratios(split)
    if stuff is not None:
        given["stuff"] = tuple(dict.fromkeys(_names(stuff, "stuff")))
    for key, value in (("seed", split_seed), ("min_area", min_instance_area),
                       ("allow_empty_split", allow_empty_split), ("mode", split_mode)):  # fmt: skip
        if value is not None:
            given[key] = value
    return LabelOptions(**given)


def _names(given: str | Iterable[str] | None, what: str = "species") -> list[str]:
    """Names as text (``"a,b"``) or a list of texts (each may be ``"a,b"`` too)."""
    if given is None:
        return []
    texts = [given] if isinstance(given, str) else list(given)
    if not all(isinstance(t, str) for t in texts):
        raise InputError(f"{what} must be names (text or a list of texts), got {given!r}")
    return [n.strip() for text in texts for n in text.split(",") if n.strip()]


def _one_species(table: dict[str, Any], overrides: dict[str, Any]) -> None:
    """A group's own species wins over settings: never silently. ``species`` given as a
    setting for every plant must agree with the species the groups name."""
    if "species" not in overrides:
        return
    named = {str(g.get("species")) for g in table.get("group", []) if isinstance(g, dict)}
    named -= {"None", str(overrides["species"])}
    if named:
        raise InputError(
            f"--set species={overrides['species']} disagrees with the species the groups "
            f"name ({', '.join(sorted(named))}, from --species or the spec); give it once"
        )


def _resource_texts(resources: Mapping[str, Any] | None) -> dict[str, str]:
    """Custom resources by name: ``NAME=AMOUNT`` texts (the command line) or numbers."""
    if resources is None:
        return {}
    if not isinstance(resources, Mapping):
        raise InputError(f"resources must be a table of NAME: AMOUNT, got {resources!r}")
    out = {}
    for name, amount in resources.items():
        if isinstance(amount, bool) or not isinstance(amount, (str, int, float)):
            raise InputError(f"--resource {name}: the amount must be a number, got {amount!r}")
        out[str(name)] = str(amount)
    return out
