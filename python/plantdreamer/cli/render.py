"""``plantdreamer render``: images of any 3DGS PLY on the evaluation orbit."""

from __future__ import annotations

import math
from pathlib import Path

import click

# What render writes into --out; --overwrite deletes these first.
RENDER_OUTPUTS = ("turntable.gif", "*.png")


@click.command()
@click.argument("ply", type=click.Path(dir_okay=False))
@click.option(
    "--out", "out_dir", type=click.Path(file_okay=False), default="renders", show_default=True
)
@click.option("--eval-views", "views", default=120, show_default=True, help="Views on the orbit.")
@click.option("--views", "views_alias", type=int, hidden=True)  # the name before --eval-views
@click.option("--resolution", default=512, show_default=True)
@click.option(
    "--distance", default=4.0, show_default=True, help="Orbit radius; the model's size is 4."
)
@click.option(
    "--up",
    type=click.Choice(["z", "y", "x", "-z", "-y", "-x"]),
    default="z",
    show_default=True,
    help="The model's up axis (captured scenes are often -y).",
)
@click.option(
    "--center",
    help="X,Y,Z in the model's own frame to orbit around [default: the opacity-weighted "
    "median of the Gaussians].",
)
@click.option(
    "--elevation", default=15.0, show_default=True, help="Degrees above the ground plane."
)
@click.option("--fovy", default=70.0, show_default=True)
@click.option("--background", default=0.75, show_default=True, help="Grey level behind the plant.")
@click.option("--turntable/--no-turntable", default=True, show_default=True)
@click.option(
    "--transforms",
    type=click.Path(),
    help="Render at the cameras of this transforms.json (model kept in its own frame) "
    "instead of the orbit.",
)
@click.option("--overwrite", is_flag=True, help="Replace the images of an earlier render in --out.")
def render(
    ply: str,
    out_dir: str,
    views: int,
    resolution: int,
    distance: float,
    elevation: float,
    fovy: float,
    background: float,
    turntable: bool,
    transforms: str | None,
    overwrite: bool,
    views_alias: int | None,
    up: str,
    center: str | None,
) -> None:
    """Render a 3DGS PLY (ours or another tool's) to PNGs, plus a turntable GIF.

    On the orbit, the model is turned so --up points up, centred on the opacity-weighted
    median of its Gaussians and scaled so the central 96% of them span 4 units: stray far
    Gaussians do not shrink the subject. With --transforms, each view is named after its frame.
    """
    from plantdreamer.errors import InputError
    from plantdreamer.eval.images import check_image_size
    from plantdreamer.io import read_splat_ply
    from plantdreamer.output_folder import claim_folder

    views = views_alias if views_alias is not None else views
    target = None if center is None else parse_center(center)
    if not 0.0 <= background <= 1.0:  # also refuses NaN
        raise InputError(f"--background must be a grey level in [0, 1], got {background}")
    if views < 1:
        raise InputError(f"--views must be at least 1, got {views}")
    check_image_size(resolution, resolution, "--resolution")
    if not (math.isfinite(distance) and distance > 0 and 0 < fovy < 180):
        raise InputError("--distance must be positive and --fovy in (0, 180) degrees")
    out = Path(out_dir)
    with claim_folder(out, overwrite=overwrite, owned=RENDER_OUTPUTS):
        if transforms is not None:
            _render_dataset_views(read_splat_ply(ply), transforms, out, background)
        else:
            _render_orbit(
                ply, out, views, resolution, distance, elevation, fovy, background, turntable,
                up, target,
            )  # fmt: skip


def parse_center(value: str) -> tuple[float, float, float]:
    from plantdreamer.errors import InputError

    try:
        xyz = tuple(float(p) for p in value.split(","))
    except ValueError:
        xyz = ()
    if len(xyz) != 3 or not all(math.isfinite(c) for c in xyz):
        raise InputError(f"--center must be X,Y,Z (three finite numbers), got {value!r}")
    return (xyz[0], xyz[1], xyz[2])


def _render_orbit(
    ply, out, views, resolution, distance, elevation, fovy, background, turntable, up, center
) -> None:
    import torch

    from plantdreamer.io import read_splat_ply
    from plantdreamer.pipeline import outputs
    from plantdreamer.pipeline.model import GaussianModel

    model = GaussianModel(outputs.to_scene_frame(read_splat_ply(ply), up=up, center=center))
    with torch.no_grad():
        frames = outputs.render_orbit(
            lambda cam: model.render([cam], background)[0][0].numpy(),
            views,
            distance,
            elevation,
            fovy,
            resolution,
        )
    outputs.write_renders(out, frames)
    if turntable:
        outputs.write_turntable(out / "turntable.gif", frames, 40)
    click.echo(f"wrote {len(frames)} views of {len(model)} Gaussians to {out}")


def _render_dataset_views(gaussians, transforms: str, out: Path, background: float) -> None:
    import numpy as np
    import torch

    from plantdreamer.atomic import write_image
    from plantdreamer.eval.datasets import scan_transforms_json
    from plantdreamer.pipeline.model import GaussianModel

    model = GaussianModel(gaussians)
    views = scan_transforms_json(transforms, images_required=False)
    out.mkdir(parents=True, exist_ok=True)
    for view in views:
        with torch.no_grad():
            rgb = model.render([view.camera], background)[0][0].numpy()
        image = (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        write_image(out / f"{Path(view.name).name}.png", image)
    click.echo(f"wrote {len(views)} views of {len(model)} Gaussians to {out}")
