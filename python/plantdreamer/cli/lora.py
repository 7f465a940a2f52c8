"""``plantdreamer lora train``: train a species LoRA from a folder of photos."""

from __future__ import annotations

import click


@click.group()
def lora() -> None:
    """Species LoRA adapters for Stable Diffusion."""


@lora.command()
@click.argument("images_dir", type=click.Path(file_okay=False, path_type=str))
@click.option("--species", default="bean", show_default=True, help="Plant species name.")
@click.option(
    "--base-model",
    default="stabilityai/stable-diffusion-2-1-base",
    show_default=True,
    help="Hub id or local folder of the Stable Diffusion model.",
)
@click.option("--rank", default=4, show_default=True, help="LoRA rank.")
@click.option("--alpha", type=int, default=None, help="LoRA alpha (default: the rank).")
@click.option("--steps", default=1500, show_default=True, help="Optimiser steps.")
@click.option("--resolution", default=512, show_default=True, help="Training crop size (px).")
@click.option("--lr", "learning_rate", default=1e-4, show_default=True, help="AdamW learning rate.")
@click.option("--batch-size", default=1, show_default=True)
@click.option("--grad-accum", default=1, show_default=True, help="Gradient accumulation steps.")
@click.option("--seed", default=0, show_default=True)
@click.option(
    "--caption-template",
    default=None,
    help="Caption for images without a <name>.txt beside them "
    "[default: the generation prompt template, 'a {species} plant in a pot'].",
)
@click.option(
    "--checkpoint-every", default=500, show_default=True, help="Steps between checkpoints."
)
@click.option("--resume", is_flag=True, help="Continue from the latest checkpoint in --out.")
@click.option("--overwrite", is_flag=True, help="Replace the outputs of an earlier run in --out.")
@click.option(
    "--mixed-precision/--no-mixed-precision",
    default=None,
    help="fp16 autocast (default: on with a CUDA GPU, off on the CPU).",
)
@click.option("--device", default=None, help="torch device (default: cuda if available).")
@click.option(
    "--validate", default=0, show_default=True, help="Sample images to render after training."
)
@click.option("--out", default=None, help="Output folder (default: lora/<species>).")
def train(images_dir: str, out: str | None, **options: object) -> None:
    """Train a LoRA on the photos in IMAGES_DIR (captions from <name>.txt or the template)."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from plantdreamer.lora.train import LoraTrainConfig, train_lora

    out = out or f"lora/{options['species']}"
    if options["caption_template"] is None:
        del options["caption_template"]  # the config's default: the generation template
    config = LoraTrainConfig(images_dir=images_dir, out=out, **options)  # type: ignore[arg-type]
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
