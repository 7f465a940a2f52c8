"""``plantdreamer dataset``: many plants in one command, on this machine or a Ray cluster."""

from __future__ import annotations

from pathlib import Path

import click

from plantdreamer.cli.dataset_help import DATASET_EXAMPLES
from plantdreamer.cli.label_options import label_options
from plantdreamer.cli.options import config_options, options_to_settings
from plantdreamer.dataset.demand import DEFAULT_CPUS, DEFAULT_GPUS
from plantdreamer.dataset.packing import PackingConfig
from plantdreamer.dataset.request import DEFAULT_MAX_RETRIES, OPTION_LIMITS
from plantdreamer.pipeline.settings.config import GenerateConfig
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


@click.command(epilog=DATASET_EXAMPLES)
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
@click.option(
    "--address",
    help="Run on Ray: a cluster's HOST:PORT, auto (the cluster this machine belongs to) or "
    "local (a private Ray started here) [default: worker processes on this machine, no Ray].",
)
@click.option(
    "--local-cpus",
    type=click.IntRange(int(OPTION_LIMITS["local_cpus"][1])),
    help="CPUs of this machine the plants use (the local workers' or a local Ray's) [all].",
)
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
    type=click.IntRange(int(OPTION_LIMITS["max_retries"][1])),
    default=DEFAULT_MAX_RETRIES,
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
    split_mode: str,
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
    from plantdreamer.cli.label_options import describe
    from plantdreamer.dataset import run_dataset
    from plantdreamer.dataset.request import dataset_request
    from plantdreamer.dataset.runner import planned_classes
    from plantdreamer.errors import DatasetStopped
    from plantdreamer.exports.dataset import check_exports_owned, check_planned_splits

    packing = options_to_settings(PackingConfig, quick_settings)
    scene_settings = options_to_settings(SceneConfig, quick_settings)
    overrides = {
        k: v
        for k, v in options_to_settings(GenerateConfig, quick_settings).items()
        if v is not None
    }
    overrides.update({k: _toml_value(v) for k, v in _key_values(settings, "--set").items()})
    request = dataset_request(
        spec=spec_file,
        species=species,
        pointcloud=pointcloud,
        seeds=seeds,
        count=count,
        seed_start=seed_start,
        settings=overrides,
        plants_per_gpu=packing["plants-per-gpu"],
        scenes=scene_seeds,
        scene_settings=scene_settings,
        address=address,
        local_cpus=local_cpus,
        cpus_per_plant=cpus_per_plant,
        gpus_per_plant=gpus_per_plant,
        resources=_key_values(resources, "--resource"),
        max_retries=max_retries,
        split=split_ratios,
        split_seed=split_seed,
        split_mode=split_mode,
        stuff=stuff,
        allow_empty_split=allow_empty_split,
        min_instance_area=min_instance_area,
        redo_changed=redo_changed,
        show_progress=not quiet,
    )
    plants, options = request.plants, request.options
    if dry_run:  # the label options' and the folder's refusals, as the run would give them
        planned = planned_classes(plants)
        check_exports_owned(Path(out_dir))
        species_of = {p.id: p.species_name for p in plants}
        check_planned_splits(Path(out_dir), species_of, options.labels, planned)
        _print_plan(plants, out_dir, options.plants_per_gpu)
        if options.scenes:
            click.echo(
                f"then {len(options.scenes)} scenes of the finished plants into {out_dir}/scenes/"
            )
        return
    try:
        report, stopped = run_dataset(request.spec, plants, out_dir, options), False
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


def _print_plan(plants, out_dir: str, plants_per_gpu: int) -> None:
    """``--dry-run``: the plan from OUT's records and folders; nothing is written."""
    from plantdreamer.dataset.manifest import Manifest
    from plantdreamer.dataset.plan import describe_plan

    out = Path(out_dir).resolve()
    for line in describe_plan(plants, Manifest(out, read_only=True), out, plants_per_gpu):
        click.echo(line)
