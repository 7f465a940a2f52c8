"""``plantdreamer render``: images of any 3DGS PLY on the evaluation orbit."""

from __future__ import annotations

import math
from pathlib import Path

import click

from plantdreamer.turntable import TURNTABLE_FORMATS, TURNTABLE_FRAMES

# What render writes into --out; --overwrite deletes these first.
RENDER_OUTPUTS = (
    "turntable.gif",
    "turntable.mp4",
    "*.png",
    "renders",
    "labels",
    "instances",
    "depth",
    "transforms.json",
)


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
@click.option(
    "--turntable",
    type=click.Choice(TURNTABLE_FORMATS),
    default="gif",
    show_default=True,
    help="turntable.gif, turntable.mp4, both or none (orbit only).",
)
@click.option(
    "--transforms",
    type=click.Path(),
    help="Render at the cameras of this transforms.json (model kept in its own frame) "
    "instead of the orbit.",
)
@click.option(
    "--labels",
    "ground_truth",
    is_flag=True,
    help="Also write the ground truth of each orbit view (labels/, instances/ from the PLY's "
    "label and instance properties; depth/, transforms.json), laid out as generate does.",
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
    turntable: str,
    transforms: str | None,
    ground_truth: bool,
    overwrite: bool,
    views_alias: int | None,
    up: str,
    center: str | None,
) -> None:
    """Render a 3DGS PLY (ours or another tool's) to PNGs, plus a turntable GIF and/or MP4.

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
    if ground_truth and transforms is not None:
        raise InputError("--labels renders the orbit; it cannot be combined with --transforms")
    if ground_truth and up != "z":
        # transforms.json poses are written in the PLY's own frame, which --up would turn.
        raise InputError("--labels writes poses in the PLY's own frame; use it with --up z")
    out = Path(out_dir)
    with claim_folder(out, overwrite=overwrite, owned=RENDER_OUTPUTS):
        if transforms is not None:
            _render_dataset_views(read_splat_ply(ply), transforms, out, background)
            return
        frames, count = _render_orbit(
            ply, out, views, resolution, distance, elevation, fovy, background, ground_truth,
            up, target,
        )  # fmt: skip
        from plantdreamer.pipeline import outputs

        outputs.write_turntables(out, frames, TURNTABLE_FRAMES, turntable)
    click.echo(f"wrote {len(frames)} views of {count} Gaussians to {out}")


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
    ply, out, views, resolution, distance, elevation, fovy, background, ground_truth, up, center
):
    """Renders the orbit into ``out`` (with ``ground_truth``, in generate's dataset layout);
    returns the frames and the Gaussian count."""
    import torch

    from plantdreamer.errors import InputError
    from plantdreamer.io import read_splat_ply
    from plantdreamer.pipeline import outputs
    from plantdreamer.pipeline.model import GaussianModel

    gaussians = read_splat_ply(ply)
    if ground_truth and gaussians.labels is None:
        raise InputError(f"{ply} has no label or instance property to render masks from")
    scene, transform = outputs.to_scene_frame(gaussians, up=up, center=center)
    model = GaussianModel(scene)
    with torch.no_grad():
        if ground_truth:  # the dataset layout: images in renders/, masks beside them
            from plantdreamer.cameras import orbit_ring
            from plantdreamer.pipeline.dataset_export import ground_truth_writer, render_views

            def render_view(camera):
                image, _, meta = model.render([camera], background)
                return outputs.to_uint8(image[0].numpy()), meta

            cameras = orbit_ring(views, distance, elevation, fovy, resolution, resolution)
            writer = ground_truth_writer(out, model, transform)
            frames = render_views(model, writer, cameras, render_view)
            outputs.write_renders(out / "renders", frames)
        else:
            frames = outputs.render_orbit(
                lambda cam: model.render([cam], background)[0][0].numpy(),
                views,
                distance,
                elevation,
                fovy,
                resolution,
            )
            outputs.write_renders(out, frames)
    return frames, len(model)


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
