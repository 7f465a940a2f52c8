"""``plantdreamer ablate``: the paper's colour-initialisation ablation on your own data."""

from __future__ import annotations

from pathlib import Path

import click

from plantdreamer.cli.options import (
    apply_old_names,
    config_from_options,
    config_options,
    hidden_old_name,
)
from plantdreamer.pipeline.model.init import COLOR_INITS
from plantdreamer.pipeline.settings.config import GenerateConfig

# The generation settings an ablation varies only through the command line.
SETTINGS = (
    "species", "seed", "steps", "resolution", "guidance", "base-model",
    "controlnet", "lora", "background",
)  # fmt: skip


@click.command()
@click.option(
    "--pointcloud", required=True, type=click.Path(dir_okay=False), help="Input cloud (PLY)."
)
@click.option("--dataset", required=True, type=click.Path(), help="Posed ground-truth images.")
@click.option(
    "--color-init",
    type=click.Choice(COLOR_INITS),
    multiple=True,
    help="The colour initialisations compared, as generate's --color-init (repeat it: "
    "--color-init noise --color-init black).  [default: every one]",
)
@hidden_old_name("--colors", "--color-init")  # earlier: one comma-separated list
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default="ablation",
    show_default=True,
    help="The folder of the table, the plot and one generate run per colour initialisation.",
)
@config_options(GenerateConfig, only=SETTINGS)
@click.option("--overwrite", is_flag=True, help="Replace the results of an earlier ablation.")
@click.option("--quiet", is_flag=True, help="No progress output.")
def ablate(pointcloud, dataset, color_init, out_dir, overwrite, quiet, **options) -> None:
    """Generate once per colour initialisation, score each against the dataset (masked PSNR),
    and write the paper-style table and bar plot."""
    from plantdreamer.errors import InputError
    from plantdreamer.eval import scan_dataset
    from plantdreamer.output_folder import claim_folder, tree
    from plantdreamer.pipeline.settings.runtime import check_inputs, check_models
    from plantdreamer.pipeline.state.run_outputs import RUN_OUTPUTS

    given = {"color_init": ",".join(color_init) or None, "old_colors": options.pop("old_colors")}
    apply_old_names(given, {"--colors": "color-init"})
    colors = given["color_init"] or ",".join(COLOR_INITS)
    base = config_from_options(GenerateConfig, options)
    settings = [c.strip() for c in colors.split(",") if c.strip()]
    unknown = sorted(set(settings) - set(COLOR_INITS))
    if not settings or unknown:
        raise InputError(f"--color-init takes {', '.join(COLOR_INITS)}; got {colors!r}")
    frames = scan_dataset(dataset)  # fail on a bad dataset before hours of generation
    first = GenerateConfig.from_settings({**base.settings(), "pointcloud": pointcloud})
    check_inputs(first)
    check_models(first)
    out = Path(out_dir)
    runs = [e for color in COLOR_INITS for e in tree(color, *RUN_OUTPUTS, "eval.json")]
    owned = ("ablation.md", "ablation.png", *runs)
    with claim_folder(out, overwrite=overwrite, owned=owned, inputs=[pointcloud]):
        _ablate(base, pointcloud, frames, settings, out, quiet)


def _ablate(base, pointcloud, frames, settings, out, quiet) -> None:
    from plantdreamer.errors import InputError
    from plantdreamer.eval import evaluate
    from plantdreamer.eval.report import write_ablation_table, write_json
    from plantdreamer.io import read_splat_ply
    from plantdreamer.pipeline import generate_plants

    background = base.train.background
    results: dict[str, float] = {}
    for color in settings:
        click.echo(f"== colour init: {color}")
        cfg = GenerateConfig.from_settings(
            {**base.settings(), "pointcloud": pointcloud, "color-init": color, "eval-views": 0}
        )
        run = generate_plants([cfg], out / color, show_progress=not quiet)[0]
        scored = evaluate(read_splat_ply(run.ply_path), frames, (background,) * 3, keep_views=0)
        write_json(scored, out / color / "eval.json", setting=color)
        value = scored.mean["masked_psnr"]
        if value is None:
            raise InputError("the dataset has no masks: masked PSNR needs plant masks")
        results[color] = value
        click.echo(f"{color}: masked PSNR {value:.2f} dB")
    table, plot = write_ablation_table(results, out)
    click.echo(table.read_text())
    click.echo(f"wrote {table} and {plot}")
