"""``plantdreamer render``: images of any 3DGS PLY on the evaluation orbit."""

from __future__ import annotations

from pathlib import Path

import click

from plantdreamer.turntable import TURNTABLE_FORMATS, TURNTABLE_FRAMES


@click.command()
@click.argument("ply", type=click.Path(dir_okay=False))
@click.option(
    "--out", "out_dir", type=click.Path(file_okay=False), default="renders", show_default=True
)
@click.option("--views", default=120, show_default=True)
@click.option("--resolution", default=512, show_default=True)
@click.option("--distance", default=4.0, show_default=True)
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
) -> None:
    """Render a 3DGS PLY (ours or another tool's) to PNGs, plus a turntable GIF and/or MP4.

    On the orbit, the model is framed as generate frames it: centred on its bounding box,
    longest side 4. With --transforms, each view is named after its frame.
    """
    import torch

    from plantdreamer.errors import InputError
    from plantdreamer.io import read_splat_ply
    from plantdreamer.pipeline import outputs
    from plantdreamer.pipeline.model import GaussianModel

    out = Path(out_dir)
    if transforms is not None:
        if ground_truth:
            raise InputError("--labels renders the orbit; it cannot be combined with --transforms")
        _render_dataset_views(read_splat_ply(ply), transforms, out, background)
        return
    gaussians = read_splat_ply(ply)
    if ground_truth and gaussians.labels is None:
        raise InputError(f"{ply} has no label or instance property to render masks from")
    scene, transform = outputs.to_scene_frame(gaussians)
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
    outputs.write_turntables(out, frames, TURNTABLE_FRAMES, turntable)
    click.echo(f"wrote {len(frames)} views of {len(model)} Gaussians to {out}")


def _render_dataset_views(gaussians, transforms: str, out: Path, background: float) -> None:
    import imageio.v3 as iio
    import numpy as np
    import torch

    from plantdreamer.eval.datasets import scan_transforms_json
    from plantdreamer.pipeline.model import GaussianModel

    model = GaussianModel(gaussians)
    views = scan_transforms_json(transforms, images_required=False)
    out.mkdir(parents=True, exist_ok=True)
    for view in views:
        with torch.no_grad():
            rgb = model.render([view.camera], background)[0][0].numpy()
        image = (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        iio.imwrite(out / f"{Path(view.name).name}.png", image)
    click.echo(f"wrote {len(views)} views of {len(model)} Gaussians to {out}")
