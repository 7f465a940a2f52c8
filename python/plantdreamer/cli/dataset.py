"""``plantdreamer dataset``: many plants in one command, on this machine or a Ray cluster."""

from __future__ import annotations

from pathlib import Path

import click

from plantdreamer.cli.label_options import label_options
from plantdreamer.cli.options import config_options, options_to_settings
from plantdreamer.dataset.engine import DEFAULT_CPUS, DEFAULT_GPUS
from plantdreamer.dataset.packing import PackingConfig
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.scenes.config import SceneConfig

_PER_PLANT = "[default: {:g} with sds, {:g} with none]"
# Generate settings with an option of their own here (any other: --set NAME=VALUE).
QUICK_SETTINGS = ("guidance", "steps", "points", "resolution", "eval-views")


def _key_values(pairs: tuple[str, ...], what: str) -> dict[str, str]:
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise click.BadParameter(f"{pair!r} is not KEY=VALUE", param_hint=what)
        out[key.strip()] = value.strip()
    return out


def _toml_value(text: str) -> object:
    """``--set steps=20`` gives an int, ``--set lora=lora/bean`` a string,
    ``--set cameras-distance=[3, 5]`` a list."""
    from plantdreamer.dataset.spec import tomllib

    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


@click.command()
@click.argument("spec_file", required=False, type=click.Path(dir_okay=False, exists=True))
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(file_okay=False),
    help="The dataset folder (plants/, manifest.jsonl, coco/, yolo/, gallery.png, README.md).",
)
@click.option(
    "--species",
    multiple=True,
    help="Without a spec: an L-System species, one group of plants each (repeat it: "
    "--species bean --species mint); with --pointcloud, the plant named in the prompts.",
)
@click.option(
    "--pointcloud",
    help="Without a spec: real plant point clouds (PLY), a file or a glob ('scans/*.ply'); "
    "each file is a plant per seed.",
)
@click.option(
    "--seeds",
    help="Without a spec: the seeds of each group's plants, as generate's: 0-7, 0,3,5 or "
    "both.  [default: 0]",
)
@click.option("--count", type=click.IntRange(1), hidden=True)  # earlier: --seeds S-(S+N-1)
@click.option("--seed-start", type=click.IntRange(0), hidden=True)
@config_options(
    GenerateConfig,
    QUICK_SETTINGS,
    with_defaults=False,
    note=" For every plant [generate's default].",
)
@click.option(
    "--set",
    "settings",
    multiple=True,
    metavar="NAME=VALUE",
    help="Any generate setting for every plant, by its option name: --set points=5000.",
)
@click.option(
    "--scenes",
    "scene_seeds",
    metavar="SEEDS",
    help="Also scenes of the finished plants (trays: scene-plants of one split together), "
    "one per seed (0-9: ten), into OUT/scenes/; their views take the views' settings.",
)
@config_options(SceneConfig, with_defaults=False, note=" With --scenes [default: 4, grid].")
@click.option("--address", help="Join a Ray cluster: auto or HOST:PORT [default: local Ray].")
@click.option("--local-cpus", type=click.IntRange(1), help="CPUs of the local Ray [all].")
@click.option(
    "--cpus-per-plant",
    type=float,
    help=_PER_PLANT.format(DEFAULT_CPUS["sds"], DEFAULT_CPUS["none"]),
)
@click.option(
    "--gpus-per-plant",
    type=float,
    help=_PER_PLANT.format(DEFAULT_GPUS["sds"], DEFAULT_GPUS["none"]),
)
@click.option(
    "--resource",
    "resources",
    multiple=True,
    metavar="NAME=AMOUNT",
    help="A custom Ray resource every plant needs.",
)
@config_options(PackingConfig, with_defaults=False, note=" [spec's, else 1]")
@click.option(
    "--max-retries",
    type=click.IntRange(0),
    default=3,
    show_default=True,
    help="Re-runs of a plant whose worker died.",
)
@click.option("--quiet", is_flag=True, help="No progress bar or summary.")
@click.option(
    "--redo-changed",
    is_flag=True,
    help="Delete and remake finished plants in OUT made with other settings (without it, "
    "a run that would do so stops and says how many).",
)
@click.option(
    "--dry-run",
    is_flag=True,
    help="List what a run would do with each plant (make, resume, skip, redo); start nothing.",
)
@label_options
def dataset(
    spec_file: str | None,
    out_dir: str,
    species: tuple[str, ...],
    pointcloud: str | None,
    seeds: str | None,
    count: int | None,
    seed_start: int | None,
    settings: tuple[str, ...],
    address: str | None,
    local_cpus: int | None,
    cpus_per_plant: float | None,
    gpus_per_plant: float | None,
    resources: tuple[str, ...],
    max_retries: int,
    quiet: bool,
    redo_changed: bool,
    dry_run: bool,
    split_ratios: str,
    split_seed: int,
    stuff: str,
    allow_empty_split: bool,
    min_instance_area: int,
    scene_seeds: str | None,
    **quick_settings: object,
) -> None:
    """Generate a dataset of plants into OUT/plants/<id>/ with OUT/manifest.jsonl.

    SPEC_FILE (TOML) lists groups of plants and their settings; without one, --species
    (or --pointcloud) and --seeds give them, as generate's do. Settings given here apply to
    every plant, over the spec's [defaults]. Plants already complete in OUT are skipped;
    finished plants of other settings are kept, and the run refused, unless --redo-changed.
    At the end, the finished plants are split by plant into train/val/test and written as
    COCO (OUT/coco/) and YOLO (OUT/yolo/) files, with OUT/gallery.png to look them over.
    """
    from pathlib import Path

    from plantdreamer.cli.label_options import describe, make_label_options
    from plantdreamer.dataset import RunOptions, expand, run_dataset
    from plantdreamer.dataset.engine import custom_resources, import_ray
    from plantdreamer.dataset.packing import packing_from
    from plantdreamer.dataset.runner import DatasetStopped, planned_classes
    from plantdreamer.dataset.spec import with_settings
    from plantdreamer.errors import InputError
    from plantdreamer.exports.dataset import check_planned_splits

    if not dry_run:
        import_ray()  # fail first, with what to install, when Ray is missing
    spec = spec_of_options(spec_file, species, pointcloud, seeds, count, seed_start)
    packing = packing_from(spec, options_to_settings(PackingConfig, quick_settings))
    from plantdreamer.dataset.scenes import with_scene_table

    spec = with_scene_table(spec, scene_seeds, options_to_settings(SceneConfig, quick_settings))
    quick = options_to_settings(GenerateConfig, dict(quick_settings))
    overrides = {k: v for k, v in quick.items() if v is not None}
    overrides.update({k: _toml_value(v) for k, v in _key_values(settings, "--set").items()})
    if "species" in overrides:  # a group's own species wins over settings: never silently
        named = {str(g.get("species")) for g in spec.get("group", []) if isinstance(g, dict)}
        named -= {"None", str(overrides["species"])}
        if named:
            raise InputError(
                f"--set species={overrides['species']} disagrees with the species the groups "
                f"name ({', '.join(sorted(named))}, from --species or the spec); give it once"
            )
    spec = with_settings(spec, overrides)
    plants = expand(spec)  # every plant's config is checked here, before Ray starts
    from plantdreamer.dataset.scenes import expand_scenes

    scenes = expand_scenes(spec)  # and every scene's settings
    from plantdreamer.dataset.plan import check_models

    check_models(plants)  # the LoRA and models found, before any plan or model load
    labels = make_label_options(
        split_ratios, split_seed, min_instance_area, allow_empty_split, stuff
    )
    if dry_run:  # the label options' refusals, as the run would give them
        planned = planned_classes(plants)
        check_planned_splits(Path(out_dir), [p.id for p in plants], labels, planned)
        _print_plan(plants, out_dir, packing.plants_per_gpu)
        if scenes:
            click.echo(f"then {len(scenes)} scenes of the finished plants into {out_dir}/scenes/")
        return
    custom = custom_resources(_key_values(resources, "--resource"))
    options = RunOptions(
        address=address,
        local_cpus=local_cpus,
        cpus_per_plant=cpus_per_plant,
        gpus_per_plant=gpus_per_plant,
        resources=custom,
        max_retries=max_retries,
        plants_per_gpu=packing.plants_per_gpu,
        show_progress=not quiet,
        redo_changed=redo_changed,
        labels=labels,
        scenes=scenes,
    )
    try:
        report, stopped = run_dataset(spec, plants, out_dir, options), False
    except DatasetStopped as stop:  # Ctrl-C or SIGTERM: the summary line still comes
        report, stopped = stop.report, True
    if stopped or report.interrupted:
        click.secho(
            f"stopped: {report.interrupted} plants interrupted (checkpoints kept), "
            f"{report.done} done, {report.failed} failed, {report.skipped} skipped; "
            "run the same command again to finish them",
            err=True,
            fg="yellow",
        )
        raise SystemExit(130)
    if report.failed:
        click.secho(
            f"error: {report.failed} of {len(plants)} plants failed "
            f"({report.done} done, {report.skipped} skipped); see {out_dir}/manifest.jsonl",
            err=True,
            fg="red",
        )
        for plant_id, error in sorted(report.failures.items()):
            click.echo(f"  {plant_id}: {error}", err=True)
        raise SystemExit(1)
    click.echo(
        f"{report.done} plants done, {report.skipped} skipped, in {report.seconds:.1f} s: {out_dir}"
    )
    if report.labels is not None:
        click.echo(describe(report.labels, out_dir))


def spec_of_options(
    spec_file: str | None,
    species: tuple[str, ...],
    pointcloud: str | None,
    seeds: str | None,
    count: int | None,
    seed_start: int | None,
) -> dict:
    """The spec file, or the one that --species / --pointcloud and --seeds describe."""
    from plantdreamer.cli.options import one_value
    from plantdreamer.dataset import load_spec
    from plantdreamer.errors import InputError
    from plantdreamer.seeds import parse_seeds, seed_range, seeds_text

    named = [n.strip() for text in species for n in text.split(",") if n.strip()]  # a,b: earlier
    if spec_file is not None:
        given = [name for name, value in (("--species", named), ("--pointcloud", pointcloud),
                 ("--seeds", seeds), ("--count", count), ("--seed-start", seed_start)) if value]  # fmt: skip
        if given:
            raise InputError(f"give a spec file or {', '.join(given)}, not both")
        return load_spec(spec_file)
    chosen = parse_seeds(seeds) if seeds is not None else None
    if count is not None or seed_start is not None or chosen is None:
        counted = seed_range(count or 1, seed_start or 0)
        if chosen is not None:
            one_value("--count / --seed-start", seeds_text(counted), "--seeds", seeds_text(chosen))
        chosen = counted
    if pointcloud is not None:
        if len(named) > 1:
            raise InputError("--pointcloud names its plant with one --species, not several")
        group = {"pointcloud": str(Path(pointcloud).resolve()), "seeds": chosen}
        return {"group": [{**group, "species": name} for name in named] or [group]}
    if not named:
        raise InputError("give a spec file, --species or --pointcloud")
    return {"group": [{"species": name, "seeds": chosen} for name in named]}


def _print_plan(plants, out_dir: str, plants_per_gpu: int) -> None:
    """``--dry-run``: the plan from OUT's records and folders; nothing is written."""
    from plantdreamer.dataset.manifest import Manifest
    from plantdreamer.dataset.plan import describe_plan

    out = Path(out_dir).resolve()
    for line in describe_plan(plants, Manifest(out, read_only=True), out, plants_per_gpu):
        click.echo(line)
