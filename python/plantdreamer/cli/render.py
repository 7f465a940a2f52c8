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
    "coco.json",
    "yolo",
)


@click.command()
@click.argument("ply", type=click.Path())
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
    help="Render at the cameras of this transforms.json (poses in the PLY's frame) instead of "
    "the orbit.",
)
@click.option(
    "--labels",
    "ground_truth",
    is_flag=True,
    help="Also write the ground truth of each view (labels/, instances/ from the PLY's label "
    "and instance properties; depth/, transforms.json), laid out as generate does.",
)
@click.option("--overwrite", is_flag=True, help="Replace the images of an earlier render in --out.")
@click.pass_context
def render(
    ctx: click.Context,
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

    PLY may be a folder written by generate (its plant.ply is rendered). A PLY with
    generate's run.json beside it is framed as generate framed it, and the orbit settings
    not given here are generate's: view i is generate's view i, and --labels writes the same
    ground truth. Any other PLY is turned so --up points up, centred on the opacity-weighted
    median of its Gaussians and scaled so the central 96% of them span 4 units: stray far
    Gaussians do not shrink the subject. With --transforms, views are rendered at its cameras.
    """
    from plantdreamer.errors import InputError
    from plantdreamer.eval.images import check_image_size
    from plantdreamer.io import read_splat_ply
    from plantdreamer.output_folder import claim_folder
    from plantdreamer.pipeline.rerender import GenerateFrame

    path = Path(ply)
    if path.is_dir():
        path = path / "plant.ply"
    if not path.is_file():
        raise FileNotFoundError(f"PLY not found: {path}")
    views = views_alias if views_alias is not None else views
    target = None if center is None else parse_center(center)
    frame = GenerateFrame.beside(path) if up == "z" and target is None else None
    if frame is not None:  # generate's orbit, for the settings not given here
        given = {
            "views": _given(ctx, "views") or views_alias is not None,
            **{name: _given(ctx, name) for name in frame.orbit if name != "views"},
        }
        orbit: dict[str, float] = {
            "views": views, "distance": distance, "elevation": elevation, "fovy": fovy,
            "resolution": resolution, "background": background,
        }  # fmt: skip
        orbit.update({k: v for k, v in frame.orbit.items() if not given[k]})
        views, resolution = int(orbit["views"]), int(orbit["resolution"])
        distance, elevation, fovy = orbit["distance"], orbit["elevation"], orbit["fovy"]
        background = orbit["background"]
    if not 0.0 <= background <= 1.0:  # also refuses NaN
        raise InputError(f"--background must be a grey level in [0, 1], got {background}")
    if views < 1:
        raise InputError(f"--views must be at least 1, got {views}")
    check_image_size(resolution, resolution, "--resolution")
    if not (math.isfinite(distance) and distance > 0 and 0 < fovy < 180):
        raise InputError("--distance must be positive and --fovy in (0, 180) degrees")
    if ground_truth and up != "z":
        # transforms.json poses are written in the PLY's own frame, which --up would turn.
        raise InputError("--labels writes poses in the PLY's own frame; use it with --up z")
    gaussians = read_splat_ply(path)
    if ground_truth and gaussians.labels is None:
        raise InputError(f"{path} has no label or instance property to render masks from")
    out = Path(out_dir)
    with claim_folder(out, overwrite=overwrite, owned=RENDER_OUTPUTS):
        if transforms is not None and not ground_truth:
            _render_dataset_views(gaussians, transforms, out, background)
            return
        scene, transform = _scene(gaussians, frame, transforms is not None, up, target)
        if transforms is not None:
            from plantdreamer.pipeline.rerender import scene_cameras

            cameras = scene_cameras(transforms, transform)
        else:
            from plantdreamer.cameras import orbit_ring

            cameras = orbit_ring(views, distance, elevation, fovy, resolution, resolution)
        frames = _render_views(scene, transform, cameras, out, background, ground_truth, path)
        if transforms is None:
            from plantdreamer.pipeline import outputs

            outputs.write_turntables(out, frames, TURNTABLE_FRAMES, turntable)
    click.echo(f"wrote {len(frames)} views of {len(gaussians)} Gaussians to {out}")


def _given(ctx: click.Context, name: str) -> bool:
    from click.core import ParameterSource

    return ctx.get_parameter_source(name) not in (ParameterSource.DEFAULT, None)


def parse_center(value: str) -> tuple[float, float, float]:
    from plantdreamer.errors import InputError

    try:
        xyz = tuple(float(p) for p in value.split(","))
    except ValueError:
        xyz = ()
    if len(xyz) != 3 or not all(math.isfinite(c) for c in xyz):
        raise InputError(f"--center must be X,Y,Z (three finite numbers), got {value!r}")
    return (xyz[0], xyz[1], xyz[2])


def _scene(gaussians, frame, own_frame: bool, up: str, center):
    """The model in the frame it is rendered in, and the transform from the PLY's frame:
    generate's (a PLY beside its run.json), the PLY's own (cameras of a transforms.json),
    or a robust framing for the orbit."""
    from plantdreamer.pipeline import outputs
    from plantdreamer.pipeline.rerender import IDENTITY, scene_gaussians

    if frame is not None:
        return frame.to_scene(gaussians), frame.transform
    if own_frame:
        return scene_gaussians(gaussians, gaussians.means.astype("float64"), IDENTITY), IDENTITY
    return outputs.to_scene_frame(gaussians, up=up, center=center)


def _render_views(scene, transform, cameras, out, background, ground_truth, ply):
    """Renders ``cameras`` into ``out`` (with ``ground_truth``, in generate's dataset layout,
    with the label files); returns the frames."""
    import torch

    from plantdreamer.pipeline import outputs
    from plantdreamer.pipeline.model import GaussianModel
    from plantdreamer.pipeline.progress import Counter

    model = GaussianModel(scene)
    with torch.no_grad(), Counter("render: views", len(cameras)) as counter:

        def render_view(camera):
            image, _, meta = model.render([camera], background)
            counter.advance()
            return outputs.to_uint8(image[0].numpy()), meta

        if not ground_truth:
            frames = [render_view(camera)[0] for camera in cameras]
            outputs.write_renders(out, frames)
            return frames
        from plantdreamer.exports.plant import write_plant_exports
        from plantdreamer.exports.points import read_class_names
        from plantdreamer.pipeline.dataset_export import ground_truth_writer, render_views

        writer = ground_truth_writer(out, model, transform, class_names=read_class_names(ply))
        frames = render_views(model, writer, cameras, render_view)
        outputs.write_renders(out / "renders", frames)
    write_plant_exports(out)
    return frames


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
