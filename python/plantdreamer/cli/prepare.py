"""``plantdreamer prepare``: clean, downsample and normalise an input point cloud."""

from __future__ import annotations

from pathlib import Path

import click


def transform_path(output: Path) -> Path:
    """Where the normalisation transform of ``output`` is written: OUTPUT.transform.json."""
    return output.with_name(output.stem + ".transform.json")


@click.command()
@click.argument("input_ply", metavar="INPUT.ply", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True, help="Output PLY.")
@click.option(
    "--target",
    type=click.IntRange(min=0),
    default=100_000,
    show_default=True,
    help="Voxel-downsample to this many points (+-5%); 0 keeps every point.",
)
@click.option(
    "--sor-neighbors",
    type=click.IntRange(min=0),
    default=20,
    show_default=True,
    help="Neighbours of statistical outlier removal; 0 skips it.",
)
@click.option("--sor-std", type=float, default=3.0, show_default=True, help="SOR std ratio.")
@click.option(
    "--normalize",
    "do_normalize",
    is_flag=True,
    help="Centre on the bounding-box midpoint, longest side --size; writes "
    "OUTPUT.transform.json to restore the original frame.",
)
@click.option("--size", type=float, default=4.0, show_default=True, help="Longest side.")
@click.option("--ascii", is_flag=True, help="Write an ascii PLY instead of binary.")
@click.option("--overwrite", is_flag=True, help="Replace OUTPUT (and its transform) if they exist.")
def prepare(
    input_ply: Path,
    output: Path,
    target: int,
    sor_neighbors: int,
    sor_std: float,
    do_normalize: bool,
    size: float,
    ascii: bool,
    overwrite: bool,
) -> None:
    """Remove outliers, downsample and (optionally) normalise INPUT.ply.

    Steps: drop non-finite points, statistical outlier removal (Open3D semantics),
    voxel grid to --target points, normalisation. Prints the count after each step.
    """
    from plantdreamer.output_folder import claim_files, output_file

    output = output_file(output, "-o/--output")
    # The transform is claimed too: a stale one beside a new, unnormalised output would lie.
    with claim_files([output, transform_path(output)], overwrite=overwrite):
        _prepare(input_ply, output, target, sor_neighbors, sor_std, do_normalize, size, ascii)


def _prepare(input_ply, output, target, sor_neighbors, sor_std, do_normalize, size, ascii) -> None:
    from plantdreamer.io import read_ply, write_ply
    from plantdreamer.prepare import prepare_cloud

    cloud = read_ply(input_ply)

    def log(step: str, count: int) -> None:
        click.echo(f"{step:<18} {count:>10,d} points")

    prepared, transform, report = prepare_cloud(
        cloud,
        target=target or None,
        sor_neighbors=sor_neighbors,
        sor_std=sor_std,
        normalize_size=size if do_normalize else None,
        log=log,
    )
    if report.voxel_size > 0:
        click.echo(f"voxel size         {report.voxel_size:.6g}")
    write_ply(output, prepared, binary=not ascii)
    click.echo(f"wrote {output}")
    if transform is not None:
        path = transform_path(output)
        transform.save(path)
        click.echo(f"wrote {path} (center {transform.center}, scale {transform.scale:.6g})")
