"""A composed scene rendered into a folder laid out as a plant folder: ``renders/``,
``labels/``, ``instances/``, ``depth/``, ``transforms.json`` (poses in the scene's input
frame: the plants' units, the tray centred on its origin), ``coco.json`` and ``yolo/``, and
``plants/view_XXX.png``, which plant each pixel shows (8-bit: 0 background, k + 1 plant k
of ``scene.json``). Views, their ground truth and label files are made exactly as a plant's
export makes them (``pipeline.export``), from the scene's Gaussians in one rasterizer pass
per view, so plants occlude each other as they stand.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plantdreamer.exports.plant import LABEL_FILES, VIEW_PNG
from plantdreamer.output_folder import tree
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pointcloud import NormalizeTransform
from plantdreamer.scenes.compose import ComposedScene

SCENE_FILE = "scene.json"  # written last: the scene is finished
PLANT_MAPS = "plants"
# What a scene writes in its folder (output_folder.Owned).
SCENE_OUTPUTS = (
    SCENE_FILE,
    "turntable.gif",
    "turntable.mp4",
    *tree("renders", VIEW_PNG),
    *tree("labels", VIEW_PNG, *tree("preview", VIEW_PNG)),
    *tree("instances", VIEW_PNG),
    *tree("depth", VIEW_PNG),
    *tree(PLANT_MAPS, VIEW_PNG),
    "transforms.json",
    *LABEL_FILES,
)


def scene_frame(composed: ComposedScene, size: float) -> NormalizeTransform:
    """The frame the scene renders in: its robust centre at the origin, its robust size
    ``size`` (as a plant's scene frame)."""
    from plantdreamer.framing import robust_center_extent

    mid, extent = robust_center_extent(composed.gaussians)
    return NormalizeTransform((float(mid[0]), float(mid[1]), float(mid[2])), size / extent)


def render_scene(composed: ComposedScene, out: Path, cfg: GenerateConfig) -> int:
    """Writes the scene's views, ground truth and label files into ``out`` (``cfg``: its
    views' settings, ``scene.config.view_config``); returns the number of views."""
    import torch

    from plantdreamer.atomic import write_image
    from plantdreamer.exports.instances import read_png
    from plantdreamer.exports.plant import write_plant_exports
    from plantdreamer.pipeline import outputs
    from plantdreamer.pipeline.export import export_plan
    from plantdreamer.pipeline.model.gaussian_model import GaussianModel
    from plantdreamer.pipeline.truth.dataset_export import ground_truth_writer, render_views
    from plantdreamer.pipeline.truth.ground_truth import GroundTruthRenderer, LabelSet

    transform = scene_frame(composed, cfg.source.scene_size)
    scene = transform.gaussians_to_scene(composed.gaussians, composed.means)
    model = GaussianModel(scene)
    plan = export_plan(cfg, scene)
    writer = ground_truth_writer(out, model, transform, True, composed.class_names)
    # Which plant each pixel shows: the plant of its instance where it has one, else the
    # plant of largest weight among those of its class (the instance rule, plants as units).
    labels = composed.gaussians.labels
    assert labels is not None  # compose makes a scene of labelled plants only
    plant_labels = np.stack([labels[:, 0], composed.plant_of], axis=1)
    plant_set = LabelSet.of(plant_labels)
    plant_maps = GroundTruthRenderer(model, plant_set)
    by_class: list[np.ndarray] = []
    oc = cfg.outputs
    frames_shown = oc.turntable_frames if plan.turns else 0  # no turntable of a rig
    views = outputs.StreamedViews(
        out / "renders", len(plan.cameras), frames_shown, oc.turntable, plan.png
    )  # each view written as it is made
    with torch.no_grad():

        def render(camera):
            view = plan.index(camera)
            image, alpha, meta = model.render([camera], plan.render_background)
            picture = plan.finish(view, image[0].numpy(), alpha[0, ..., 0].numpy())
            by_class.append(np.r_[plant_set.instances, -1][plant_maps(camera, meta).instance])
            return outputs.to_uint8(picture), meta

        records = [{**r, "plant_path": f"{PLANT_MAPS}/view_{i:03d}.png"}
                   for i, r in enumerate(plan.records)]  # fmt: skip
        render_views(model, writer, plan.cameras, render, views.add, records)
    assert writer.instance_values is not None and writer.label_set is not None
    ids = np.zeros(int(writer.instance_values.max(initial=0)) + 1, dtype=np.int64)
    ids[writer.instance_values] = writer.label_set.instances
    offsets = np.asarray(composed.instance_offsets)
    (out / PLANT_MAPS).mkdir(parents=True, exist_ok=True)
    for view, plants in enumerate(by_class):
        instance = read_png(out / "instances" / f"view_{view:03d}.png").astype(np.int64)
        own = np.searchsorted(offsets, ids[instance], side="right") - 1
        plants = np.where(instance > 0, own, plants)
        write_image(out / PLANT_MAPS / f"view_{view:03d}.png", (plants + 1).astype(np.uint8))
    views.write_turntables(out)
    write_plant_exports(out)
    return views.written
