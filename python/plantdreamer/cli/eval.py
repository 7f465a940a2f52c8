"""``plantdreamer eval``: score a 3DGS PLY against posed ground-truth images."""

from __future__ import annotations

from pathlib import Path

import click

from plantdreamer.cli.options import config_options, options_to_settings
from plantdreamer.pipeline.settings.config import GenerateConfig


@click.command(name="eval")
@click.argument("ply", type=click.Path(path_type=Path))
@click.option(
    "--dataset",
    required=True,
    type=click.Path(path_type=Path),
    help="transforms.json (or its directory) or a COLMAP text model directory.",
)
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    default=Path("report.md"),
    show_default=True,
    help="Markdown report; the JSON and the image strip are written beside it.",
)
@config_options(GenerateConfig, only=("background",))  # generate's, its name and default
@click.option(
    "--strip-views",
    type=click.IntRange(0),
    default=4,
    show_default=True,
    help="Views shown in the image strip.",
)
@click.option("--overwrite", is_flag=True, help="Replace an earlier report at --out.")
def eval_command(
    ply: Path, dataset: Path, out: Path, strip_views: int, overwrite: bool, **options: float
) -> None:
    """Render PLY at every ground-truth camera and report masked PSNR, PSNR, SSIM and IoU.
    RGBA ground truth is composited over --background too."""
    from plantdreamer.errors import InputError
    from plantdreamer.eval import scan_dataset
    from plantdreamer.io import check_ply_file
    from plantdreamer.output_folder import claim_files, output_file

    grey = options_to_settings(GenerateConfig, options)["background"]
    if not 0.0 <= grey <= 1.0:  # also refuses NaN
        raise InputError(f"--background must be a grey level in [0, 1], got {grey}")
    bg = (grey, grey, grey)
    if not ply.is_file():
        raise FileNotFoundError(f"model not found: {ply}")
    out = output_file(out, "--out")
    if out.suffix.lower() == ".json":  # the JSON report is written beside the markdown
        raise InputError(
            f"--out names the markdown report and its JSON goes beside it; give "
            f"{out.with_suffix('.md')} rather than {out}"
        )
    strip_path = out.with_name(out.stem + "_strip.png")
    frames = scan_dataset(dataset)  # checked before --overwrite deletes the earlier report
    check_ply_file(ply, "model")
    inputs = [ply, *(p for f in frames for p in (f.image_path, f.mask_path) if p is not None)]
    outs = [out, out.with_suffix(".json"), strip_path]
    with claim_files(outs, overwrite=overwrite, inputs=inputs):
        _evaluate(ply, dataset, frames, out, bg, strip_views, strip_path)


def _evaluate(
    ply: Path, dataset: Path, frames: list, out: Path, bg, strip_views: int, strip_path: Path
) -> None:
    from plantdreamer.eval import FrameMetrics, evaluate
    from plantdreamer.eval.report import write_image_strip, write_json, write_markdown

    try:
        from plantdreamer.io import read_splat_ply
    except ImportError as exc:
        from plantdreamer.errors import PlantDreamerError

        raise PlantDreamerError("3DGS PLY reading is not available in this build") from exc
    gaussians = read_splat_ply(ply)
    click.echo(f"{len(gaussians)} Gaussians, {len(frames)} views from {dataset}")

    def progress(i: int, m: FrameMetrics) -> None:
        shown = f"masked PSNR {m.masked_psnr:.2f} dB" if m.masked_psnr is not None else "no mask"
        click.echo(f"[{i + 1}/{len(frames)}] {m.name}: PSNR {m.psnr:.2f} dB, {shown}")

    result = evaluate(gaussians, frames, bg, keep_views=strip_views, on_frame=progress)
    strip = None
    if result.views:
        strip = write_image_strip(result.views, strip_path)
    details = {"model": str(ply), "dataset": str(dataset)}
    write_markdown(result, out, title=f"Evaluation of {ply.name}", strip=strip, details=details)
    json_path = write_json(result, out.with_suffix(".json"), model=str(ply), dataset=str(dataset))
    for name, value in result.mean.items():
        click.echo(f"{name:<12} {'n/a' if value is None else f'{value:.4f}'}")
    click.echo(f"wrote {out}, {json_path}" + (f", {strip}" if strip else ""))
