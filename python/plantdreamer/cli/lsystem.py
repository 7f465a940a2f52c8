"""``plantdreamer lsystem``: grow a procedural plant and write its points and/or mesh."""

from __future__ import annotations

from pathlib import Path

import click

from plantdreamer.cli.options import apply_old_names, hidden_old_name
from plantdreamer.lsystem.growth import FULL_GROWN
from plantdreamer.prepare import TARGET_POINTS

MESH_FORMATS = ("glb", "gltf", "ply", "obj", "stl", "off")


@click.command()
@click.argument("species", required=False)
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Random seed; the same species and seed give the same files.")  # fmt: skip
@click.option(
    "-o",
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Point cloud PLY (binary; colours, normals, label and instance per point).",
)
@hidden_old_name("--output", "--out", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--mesh",
    "mesh_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Mesh file with vertex colours; format from the suffix: " + ", ".join(MESH_FORMATS),
)
@click.option("--points", type=click.IntRange(min=1), default=TARGET_POINTS, show_default=True,
              help="Points sampled uniformly over the surface for -o (generate's default).")  # fmt: skip
@click.option(
    "--growth",
    type=click.FloatRange(0.0, FULL_GROWN, min_open=True),
    default=FULL_GROWN,
    show_default=True,
    help="Growth stage in (0, 1]: the fraction of the species' derivation steps (1: "
    "full-grown); leaves keep their ids across stages (docs/traits.md).",
)
@click.option("--list", "list_only", is_flag=True, help="List the species and exit.")
@click.option("--overwrite", is_flag=True, help="Replace -o and --mesh if they exist.")
def lsystem(
    species: str | None,
    seed: int,
    out: Path | None,
    mesh_path: Path | None,
    points: int,
    growth: float,
    list_only: bool,
    overwrite: bool,
    **old: Path | None,
) -> None:
    """Grow a potted SPECIES plant from a stochastic L-System (metres, z up, soil at z = 0)."""
    old["out"] = out
    apply_old_names(old, {"--output": "out"})
    output = old["out"]
    from plantdreamer.lsystem import list_species
    from plantdreamer.lsystem.species import get_species

    if list_only:
        for name in list_species():
            click.echo(f"{name:<14} {get_species(name).summary}")
        return
    if species is None:
        raise click.UsageError("name a SPECIES (see --list)")
    if output is None and mesh_path is None:
        raise click.UsageError("nothing to write: give -o plant.ply and/or --mesh plant.glb")
    if mesh_path is not None and mesh_path.suffix.lower().lstrip(".") not in MESH_FORMATS:
        raise click.UsageError(
            f"--mesh {mesh_path}: unknown mesh format; use one of .{', .'.join(MESH_FORMATS)}"
        )

    from plantdreamer.errors import PlantDreamerError
    from plantdreamer.lsystem import OrganClass, generate_plant, sample_points
    from plantdreamer.output_folder import new_file

    if output is not None:
        output = new_file(output, "-o", overwrite=overwrite)
    if mesh_path is not None:
        mesh_path = new_file(mesh_path, "--mesh", overwrite=overwrite)
    if output is not None and mesh_path is not None and output.resolve() == mesh_path.resolve():
        raise click.UsageError("-o and --mesh name the same file")

    if output is not None:
        try:
            from plantdreamer.io import write_ply
        except ModuleNotFoundError as exc:
            if exc.name != "plantdreamer.io":
                raise
            raise PlantDreamerError(
                "-o needs plantdreamer.io (PLY writing), which this installation lacks; use --mesh"
            ) from None

    mesh = generate_plant(species, seed, growth)
    organs = (mesh.labels == OrganClass.LEAF) | (mesh.labels == OrganClass.STEM)
    height = float(mesh.vertices[organs, 2].max()) if organs.any() else 0.0
    click.echo(
        f"{species} seed {seed}: {mesh.n_leaves} leaves, height {height:.3f} m, "
        f"{len(mesh.vertices)} vertices, {len(mesh.faces)} faces"
    )
    if mesh_path is not None:
        from plantdreamer.atomic import atomic_path

        with atomic_path(mesh_path) as tmp:
            mesh.to_trimesh().export(tmp, file_type=mesh_path.suffix.lower().lstrip("."))
        click.echo(f"wrote {mesh_path}")
    if output is not None:
        write_ply(output, sample_points(mesh, n=points, seed=seed), binary=True)
        click.echo(f"wrote {output} ({points} points)")
