"""``plantdreamer render``: images of any 3DGS PLY on the evaluation orbit."""

from __future__ import annotations

import math
import re
from pathlib import Path, PurePath
from typing import Any

import click

from plantdreamer.cli import render_transforms
from plantdreamer.cli.options import (
    apply_old_names,
    config_options,
    old_names,
    options_to_settings,
    typed_options,
)
from plantdreamer.pipeline.rerender import ORBIT, VIEWS
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pipeline.settings.train_config import AUTO_RESOLUTION
from plantdreamer.turntable import TURNTABLE_FRAMES

# The orbit, render size, background and turntable are generate's settings, under generate's
# names and defaults (a size left open is generate's on the CPU, where render renders).
ORBIT_SETTINGS = (*ORBIT, "turntable", *VIEWS)
# The names render gave them before (hidden, still accepted).
OLD_NAMES = {
    "--views": "eval-views", "--distance": "eval-distance", "--elevation": "eval-elevation-deg",
    "--fovy": "eval-fovy-deg",
}  # fmt: skip

# What render writes into --out in each mode (output_folder.Owned); --overwrite deletes
# these first, never a user's other pictures nor what another mode writes.
TURNTABLES = ("turntable.gif", "turntable.mp4")
ORBIT_OUTPUTS = (*TURNTABLES, re.compile(r"view_\d{3,}\.png"))  # the views, the turntable


def render_outputs(ground_truth: bool, transforms: bool, files: list[str]) -> tuple:
    """What a render of this mode writes: with ``ground_truth``, generate's layout of the
    views (``FINAL_OUTPUTS`` less plant.ply and run.json; the turntable only on the orbit);
    at a transforms.json's cameras, the ``files`` named from its frames; else the orbit's
    views and turntable."""
    if ground_truth:
        from plantdreamer.pipeline.state.run_outputs import FINAL_OUTPUTS

        kept = tuple(e for e in FINAL_OUTPUTS if e not in ("run.json", "plant.ply", *TURNTABLES))
        return kept if transforms else (*TURNTABLES, *kept)
    if transforms:
        folders = sorted({p for f in files for p in map(str, PurePath(f).parents) if p != "."})
        return (*(f"{d}/" for d in folders), *files)
    return ORBIT_OUTPUTS


# The files a --transforms render wrote (named by its frames, so no pattern finds them),
# with their digests: --overwrite deletes those it can prove it wrote (render_transforms).
VIEWS_RECORD = render_transforms.VIEWS_RECORD


@click.command()
@click.argument("ply", type=click.Path())
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default="renders",
    show_default=True,
    help="The folder of the views (and, with --labels, their ground truth).",
)
@config_options(GenerateConfig, only=ORBIT_SETTINGS)
@old_names(GenerateConfig, OLD_NAMES)
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
    transforms: str | None,
    ground_truth: bool,
    overwrite: bool,
    up: str,
    center: str | None,
    **options: Any,
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
    given = typed_options(ctx) | apply_old_names(options, OLD_NAMES)
    orbit = options_to_settings(GenerateConfig, options)
    target = None if center is None else parse_center(center)
    frame = GenerateFrame.beside(path) if up == "z" and target is None else None
    if frame is not None:  # generate's orbit, for the settings not given here
        typed = {k for k in frame.orbit if k.replace("-", "_") in given}
        orbit.update({k: v for k, v in frame.orbit.items() if k not in typed})
    if orbit["resolution"] is None:
        orbit["resolution"] = AUTO_RESOLUTION["cpu"]
    views, resolution = int(orbit["eval-views"]), int(orbit["resolution"])
    distance, elevation = orbit["eval-distance"], orbit["eval-elevation-deg"]
    fovy, background, turntable = orbit["eval-fovy-deg"], orbit["background"], orbit["turntable"]
    if not 0.0 <= background <= 1.0:  # also refuses NaN
        raise InputError(f"--background must be a grey level in [0, 1], got {background}")
    if views < 1:
        raise InputError(f"--eval-views must be at least 1, got {views}")
    check_image_size(resolution, resolution, "--resolution")
    # No distance: the orbit is framed on the model (framing.framed_distance), as generate's.
    if not ((distance is None or (math.isfinite(distance) and distance > 0)) and 0 < fovy < 180):
        raise InputError("--eval-distance must be positive and --eval-fovy-deg in (0, 180) degrees")
    from plantdreamer.views import ViewsConfig

    looks = ViewsConfig.from_settings(orbit)  # the rig, background and jitter, as generate's
    if transforms is not None:  # its own cameras, on the grey
        looks_typed = [f"--{n}" for n in VIEWS if n != "seed" and n.replace("-", "_") in given]
        if looks_typed:
            raise InputError(f"--transforms renders at its own cameras: not with {looks_typed[0]}")
        looks = ViewsConfig()
    looks.validate()
    if ground_truth and up != "z":
        # transforms.json poses are written in the PLY's own frame, which --up would turn.
        raise InputError("--labels writes poses in the PLY's own frame; use it with --up z")
    gaussians = read_splat_ply(path)
    if ground_truth and gaussians.labels is None:
        raise InputError(f"{path} has no label or instance property to render masks from")
    out = Path(out_dir)
    views_at: list = []
    files: list[str] = []
    inputs: list[Path] = [path]
    if transforms is not None:
        from plantdreamer.eval.datasets import _transforms_file, scan_transforms_json

        inputs.append(_transforms_file(Path(transforms)))
        if not ground_truth:
            views_at = scan_transforms_json(transforms, images_required=False)
            files = render_transforms.view_files(views_at, transforms)
            inputs += [Path(p) for v in views_at for p in (v.image_path, v.mask_path) if p]
    # The cameras, checked before anything is written: a refused command writes nothing.
    scene = transform = plan = None
    if views_at:
        cameras = [v.camera for v in views_at]
    else:
        scene, transform = _scene(gaussians, frame, transforms is not None, up, target)
        from plantdreamer.views import ViewPlan, plan_views

        if transforms is not None:
            from plantdreamer.pipeline.rerender import scene_cameras

            cameras = scene_cameras(transforms, transform)
            plan = ViewPlan(cameras, [{} for _ in cameras], background)
        else:

            def orbit_views():
                from plantdreamer.cameras import orbit_ring
                from plantdreamer.framing import framed_distance

                framed = distance  # else generate's framing (of a plant without views too)
                if framed is None:
                    framed = framed_distance(scene, views, elevation, fovy, resolution, resolution)
                ring = orbit_ring(views, framed, elevation, fovy, resolution, resolution)
                return ring, framed

            seed = int(orbit["seed"])
            plan = plan_views(looks, scene, seed, views, fovy, resolution, background, orbit_views)
            cameras = plan.cameras
    for i, camera in enumerate(cameras):
        camera.check_renderable(f"camera {i}")
    earlier = render_transforms.proven_views(out) if overwrite else []
    # the record last: a stopped --overwrite leaves it, naming what is still to delete
    named = [*files, *earlier] if transforms is not None else files  # and their folders
    owned = [*render_outputs(ground_truth, transforms is not None, named), *earlier, VIEWS_RECORD]
    with claim_folder(out, overwrite=overwrite, owned=owned, inputs=inputs):
        if views_at:
            render_transforms.render_dataset_views(gaussians, views_at, files, out, background)
            return
        turntables = "none" if transforms is not None else turntable
        written = _render_views(scene, transform, plan, out, ground_truth, path, turntables)
    click.echo(f"wrote {written} views of {len(gaussians)} Gaussians to {out}")


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
    from plantdreamer.framing import to_scene_frame
    from plantdreamer.pipeline.rerender import IDENTITY

    if frame is not None:
        return frame.to_scene(gaussians), frame.transform
    if own_frame:
        return gaussians, IDENTITY
    return to_scene_frame(gaussians, up=up, center=center)


def _render_views(scene, transform, plan, out, ground_truth, ply, turntable):
    """Renders the views of ``plan`` into ``out`` (with ``ground_truth``, in generate's
    dataset layout, with the label files), each view written as it is made
    (``outputs.StreamedViews``: the turntable's frames are all it keeps); returns the
    number of views."""
    import torch

    from plantdreamer.pipeline import outputs
    from plantdreamer.pipeline.model.gaussian_model import GaussianModel
    from plantdreamer.pipeline.progress import Counter

    model = GaussianModel(scene)
    cameras = plan.cameras
    folder = out / "renders" if ground_truth else out
    frames_shown = TURNTABLE_FRAMES if plan.turns else 0  # no turntable of a rig
    views = outputs.StreamedViews(folder, len(cameras), frames_shown, turntable, plan.png)
    with torch.no_grad(), Counter("render: views", len(cameras)) as counter:

        def render_view(camera):
            image, alpha, meta = model.render([camera], plan.render_background)
            counter.advance()
            picture = plan.finish(plan.index(camera), image[0].numpy(), alpha[0, ..., 0].numpy())
            return outputs.to_uint8(picture), meta

        if not ground_truth:
            for i, camera in enumerate(cameras):
                views.add(i, render_view(camera)[0])
        else:
            from plantdreamer.exports.points import read_class_names
            from plantdreamer.pipeline.truth.dataset_export import ground_truth_writer, render_views

            names = read_class_names(ply)
            writer = ground_truth_writer(out, model, transform, class_names=names)
            render_views(model, writer, cameras, render_view, views.add, plan.records)
    views.write_turntables(out)
    if ground_truth:
        from plantdreamer.exports.plant import write_plant_exports

        write_plant_exports(out)
    return views.written
