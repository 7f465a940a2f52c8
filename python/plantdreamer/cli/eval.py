"""``plantdreamer eval``: score a 3DGS PLY against posed ground-truth images."""

from __future__ import annotations

from pathlib import Path

import click

from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.settings import by_name

# generate's --background (the grey its views are rendered on), the default here too.
GREY = by_name(GenerateConfig)["background"].default


def parse_background(value: str) -> tuple[float, float, float]:
    """``"R,G,B"`` with components in [0, 1] (e.g. ``0.75,0.75,0.75``), or one grey level
    as generate and render take it (``0.75``)."""
    from plantdreamer.errors import InputError

    parts = [p.strip() for p in value.split(",")]
    try:
        rgb = tuple(float(p) for p in parts)
    except ValueError:
        rgb = ()
    if len(rgb) == 1:
        rgb = rgb * 3
    if len(rgb) != 3 or not all(0.0 <= c <= 1.0 for c in rgb):
        raise InputError(f"--background must be a grey level or R,G,B in [0, 1], got {value!r}")
    return (rgb[0], rgb[1], rgb[2])


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
@click.option(
    "--background",
    default=str(GREY),
    show_default=True,
    help="Render background: a grey level (as generate's) or R,G,B, in [0, 1]; RGBA images "
    "are composited over it too.",
)
@click.option("--strip-views", default=4, show_default=True, help="Views shown in the image strip.")
@click.option("--overwrite", is_flag=True, help="Replace an earlier report at --out.")
def eval_command(
    ply: Path, dataset: Path, out: Path, background: str, strip_views: int, overwrite: bool
) -> None:
    """Render PLY at every ground-truth camera and report masked PSNR, PSNR, SSIM and IoU."""
    from plantdreamer.errors import InputError
    from plantdreamer.eval import scan_dataset
    from plantdreamer.io import check_ply_file
    from plantdreamer.output_folder import claim_files, output_file

    bg = parse_background(background)
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
