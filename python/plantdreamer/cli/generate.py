"""``plantdreamer generate``: a species or a point cloud in, a 3DGS plant out."""

from __future__ import annotations

from pathlib import Path

import click


@click.command()
@click.option(
    "--species",
    help="L-System species to generate (see `plantdreamer lsystem --list`); with "
    "--pointcloud, the plant named in the prompts.",
)
@click.option(
    "--pointcloud", type=click.Path(dir_okay=False), help="A real plant point cloud (PLY)."
)
@click.option("--seed", default=0, show_default=True, help="Seed of the plant, cameras and noise.")
@click.option(
    "--out", "out_dir", type=click.Path(file_okay=False), default="out", show_default=True
)
@click.option("--steps", default=3600, show_default=True)
@click.option(
    "--resolution", type=int, help="Training render size [default: 512 on CPU, 768 on GPU]."
)
@click.option(
    "--points", "n_points", default=100_000, show_default=True, help="Points to start from."
)
@click.option("--guidance", type=click.Choice(["sds", "none"]), default="sds", show_default=True)
@click.option("--base-model", default="stabilityai/stable-diffusion-2-1-base", show_default=True)
@click.option("--controlnet", default="thibaud/controlnet-sd21-depth-diffusers", show_default=True)
@click.option("--lora", help="Species LoRA: a folder or .safetensors file (diffusers format).")
@click.option("--guidance-scale", default=100.0, show_default=True)
@click.option(
    "--sds-resolution", default=512, show_default=True, help="Image size given to the VAE."
)
@click.option(
    "--schedule", type=click.Choice(["paper", "released"]), default="paper", show_default=True
)
@click.option(
    "--color-init",
    type=click.Choice(["original", "noise", "black", "white"]),
    default="original",
    show_default=True,
)
@click.option("--sh-degree", default=0, show_default=True, help="SH degree optimised.")
@click.option(
    "--sh-degree-export",
    type=click.IntRange(0, 3),
    help="Pad or cut SH in plant.ply (3 for strict viewers).",
)
@click.option("--cull-threshold", default=3.0, show_default=True, help="C in V > mean + C std.")
@click.option(
    "--eval-views", default=120, show_default=True, help="Renders on the evaluation orbit."
)
@click.option("--checkpoint-every", default=500, show_default=True)
@click.option(
    "--resume",
    "resume_dir",
    type=click.Path(file_okay=False),
    help="Continue the run in this folder.",
)
@click.option("--quiet", is_flag=True, help="No progress output.")
def generate(resume_dir: str | None, out_dir: str, quiet: bool, **options) -> None:
    """Generate a 3DGS plant; writes plant.ply, renders/, turntable.gif, run.json, log.csv."""
    from plantdreamer.pipeline import GenerateConfig, RunInterrupted
    from plantdreamer.pipeline import generate as run_generate

    try:
        if resume_dir is not None:
            result = run_generate(None, resume_dir, resume=True, show_progress=not quiet)
        else:
            result = run_generate(GenerateConfig(**options), out_dir, show_progress=not quiet)
    except RunInterrupted as stop:
        click.secho(
            f"interrupted at step {stop.step}; checkpoint written. "
            f"Continue with: plantdreamer generate --resume {stop.out_dir}",
            err=True,
            fg="yellow",
        )
        raise SystemExit(130) from None
    click.echo(
        f"wrote {result.ply_path} ({result.gaussians} Gaussians) and renders in {Path(result.out_dir)}"
    )
