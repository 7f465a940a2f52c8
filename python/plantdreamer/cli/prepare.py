"""``plantdreamer prepare``: clean, downsample and normalise an input point cloud."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from plantdreamer.cli.options import (
    apply_old_names,
    config_options,
    hidden_old_name,
    old_names,
    options_to_settings,
)
from plantdreamer.pipeline.settings.config import GenerateConfig

# generate's input-section settings that prepare applies, under their names and defaults.
PREPARE_SETTINGS = (
    "points", "sor-neighbors", "sor-std", "sor-after-voxel", "downsample-tolerance", "scene-size",
)  # fmt: skip
OLD_NAMES = {"--target": "points", "--size": "scene-size"}  # prepare's earlier names (hidden)
OLD_OUT = {"--output": "out"}  # -o's earlier long name, as lsystem's


def transform_path(output: Path) -> Path:
    """Where the normalisation transform of ``output`` is written: OUTPUT.transform.json."""
    return output.with_name(output.stem + ".transform.json")


@click.command()
@click.argument("input_ply", metavar="INPUT.ply", type=click.Path(path_type=Path))
@click.option("-o", "--out", type=click.Path(path_type=Path), help="Output PLY.  [required]")
@hidden_old_name("--output", "--out", type=click.Path(path_type=Path))
@config_options(GenerateConfig, only=PREPARE_SETTINGS)
@old_names(GenerateConfig, OLD_NAMES)
@click.option(
    "--normalize",
    "do_normalize",
    is_flag=True,
    help="Centre on the bounding-box midpoint, longest side --scene-size; writes "
    "OUT.transform.json to restore the original frame.",
)
@click.option("--ascii", is_flag=True, help="Write an ascii PLY instead of binary.")
@click.option("--overwrite", is_flag=True, help="Replace OUT (and its transform) if they exist.")
def prepare(
    input_ply: Path,
    out: Path | None,
    do_normalize: bool,
    ascii: bool,
    overwrite: bool,
    **options: Any,
) -> None:
    """Remove outliers, downsample and (optionally) normalise INPUT.ply, as generate
    prepares a --pointcloud (the same settings, names and defaults).

    Steps: drop non-finite points, statistical outlier removal (Open3D semantics; 0
    --sor-neighbors skips it), voxel grid to --points (0 keeps every point, as generate's),
    normalisation.
    Prints the count after each step.
    """
    from plantdreamer.errors import InputError
    from plantdreamer.io import check_ply_file
    from plantdreamer.output_folder import claim_files, output_file

    apply_old_names(options, OLD_NAMES)
    options["out"] = out
    apply_old_names(options, OLD_OUT)
    if options["out"] is None:
        raise click.UsageError("Missing option '-o' / '--out'.")
    output = output_file(options.pop("out"), "-o/--out")
    check_ply_file(input_ply, "INPUT.ply")  # before --overwrite deletes anything
    values = options_to_settings(GenerateConfig, options)
    for name in ("points", "sor-neighbors"):
        if values[name] < 0:
            raise InputError(f"--{name} must not be negative, got {values[name]}")
    # The transform is claimed too: a stale one beside a new, unnormalised output would lie.
    with claim_files([output, transform_path(output)], overwrite=overwrite, inputs=[input_ply]):
        _prepare(input_ply, output, values, do_normalize, ascii)


def _prepare(input_ply, output, values, do_normalize, ascii) -> None:
    from plantdreamer.io import read_ply, write_ply
    from plantdreamer.prepare import prepare_cloud

    cloud = read_ply(input_ply)

    def log(step: str, count: int) -> None:
        click.echo(f"{step:<18} {count:>10,d} points")

    prepared, transform, report = prepare_cloud(
        cloud,
        target=values["points"] or None,
        sor_neighbors=values["sor-neighbors"],
        sor_std=values["sor-std"],
        normalize_size=values["scene-size"] if do_normalize else None,
        tolerance=values["downsample-tolerance"],
        log=log,
        sor_after_voxel=values["sor-after-voxel"],
    )
    if report.voxel_size > 0:
        click.echo(f"voxel size         {report.voxel_size:.6g}")
    write_ply(output, prepared, binary=not ascii)
    click.echo(f"wrote {output}")
    if transform is not None:
        path = transform_path(output)
        transform.save(path)
        click.echo(f"wrote {path} (center {transform.center}, scale {transform.scale:.6g})")
