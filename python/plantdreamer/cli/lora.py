"""``plantdreamer lora train``: train a species LoRA from a folder of photos."""

from __future__ import annotations

import click

from plantdreamer.cli.options import (
    apply_old_names,
    config_options,
    hidden_old_name,
    options_to_settings,
)
from plantdreamer.lora.config import LoraTrainConfig

OLD_NAMES = {"--caption-template": "prompt-template"}  # its earlier name (hidden)


@click.group()
def lora() -> None:
    """Species LoRA adapters for Stable Diffusion."""


@lora.command()
@click.argument("images_dir", type=click.Path(file_okay=False, path_type=str))
@config_options(LoraTrainConfig)
@hidden_old_name("--caption-template", "--prompt-template")
@click.option(
    "--dry-run",
    is_flag=True,
    help="Check the settings and photos and print the size each photo is trained at; "
    "no model loads, nothing is written.",
)
def train(images_dir: str, dry_run: bool, **options: object) -> None:
    """Train a LoRA on the photos in IMAGES_DIR (captions from <name>.txt or the template)."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from plantdreamer.lora.train import train_lora

    apply_old_names(options, OLD_NAMES)
    values = options_to_settings(LoraTrainConfig, options)
    config = LoraTrainConfig.from_settings(images_dir, values)
    if dry_run:
        from plantdreamer.lora.dataset import photo_sizes

        config.check()
        for p in photo_sizes(config.images_dir, config.resolution):
            (w, h), (rw, rh) = p.size, p.resized
            click.echo(f"{p.path.name}: {w} x {h} -> {rw} x {rh}")
        return
    with Progress(
        TextColumn("[bold]lora[/bold] step {task.completed}/{task.total}"),
        BarColumn(),
        TextColumn("loss {task.fields[loss]:.4f}"),
        TimeRemainingColumn(),
        transient=True,
    ) as bar:
        task = bar.add_task("train", total=config.steps, loss=float("nan"))

        def report(step: int, steps: int, loss: float) -> None:
            bar.update(task, completed=step, loss=loss)

        result = train_lora(config, progress=report)
    click.echo(f"wrote {result.weights}")
    click.echo(f"wrote {result.metadata}")
    click.echo(
        f"held-out denoising loss {result.eval_loss_before:.4f} -> {result.eval_loss_after:.4f}"
    )
    for path in result.validation_images:
        click.echo(f"sample {path}")
