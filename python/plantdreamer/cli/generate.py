"""``plantdreamer generate``: a species or a point cloud in, a 3DGS plant out.

The run's options are the settings of ``GenerateConfig`` (defaults, choices and help come
from the dataclass); this module only adds the output folder, ``--resume`` and ``--quiet``.
"""

from __future__ import annotations

from pathlib import Path

import click

from plantdreamer.cli.options import config_from_options, config_options
from plantdreamer.pipeline.config import GenerateConfig


def build_command() -> click.Command:
    """The command, with options read from ``GenerateConfig`` as it is now."""

    @click.command(name="generate")
    @config_options(GenerateConfig)
    @click.option(
        "--out", "out_dir", type=click.Path(file_okay=False), default="out", show_default=True
    )
    @click.option(
        "--resume",
        "resume_dir",
        type=click.Path(file_okay=False),
        help="Continue the run in this folder.",
    )
    @click.option("--quiet", is_flag=True, help="No progress output.")
    def generate(resume_dir: str | None, out_dir: str, quiet: bool, **options) -> None:
        """Generate a 3DGS plant; writes plant.ply, renders/, turntable.gif, run.json, log.csv,
        and ground truth per view: labels/, instances/, depth/, transforms.json."""
        from plantdreamer.pipeline import RunInterrupted
        from plantdreamer.pipeline import generate as run_generate

        try:
            if resume_dir is not None:
                result = run_generate(None, resume_dir, resume=True, show_progress=not quiet)
            else:
                cfg = config_from_options(GenerateConfig, options)
                result = run_generate(cfg, out_dir, show_progress=not quiet)
        except RunInterrupted as stop:
            click.secho(
                f"interrupted at step {stop.step}; checkpoint written. "
                f"Continue with: plantdreamer generate --resume {stop.out_dir}",
                err=True,
                fg="yellow",
            )
            raise SystemExit(130) from None
        click.echo(
            f"wrote {result.ply_path} ({result.gaussians} Gaussians) "
            f"and renders in {Path(result.out_dir)}"
        )

    return generate


generate = build_command()
