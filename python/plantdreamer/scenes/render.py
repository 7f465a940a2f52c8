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
from plantdreamer.pipeline.config import GenerateConfig
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
    from plantdreamer.exports.plant import write_plant_exports
    from plantdreamer.pipeline import outputs
    from plantdreamer.pipeline.dataset_export import ground_truth_writer, render_views
    from plantdreamer.pipeline.export import export_plan
    from plantdreamer.pipeline.ground_truth import GroundTruthRenderer, LabelSet
    from plantdreamer.pipeline.model import GaussianModel

    transform = scene_frame(composed, cfg.source.scene_size)
    scene = transform.gaussians_to_scene(composed.gaussians, composed.means)
    model = GaussianModel(scene)
    plan = export_plan(cfg, scene)
    writer = ground_truth_writer(out, model, transform, True, composed.class_names)
    plant_labels = np.stack([composed.plant_of, np.full_like(composed.plant_of, -1)], axis=1)
    plant_set = LabelSet.of(plant_labels)
    plant_maps = GroundTruthRenderer(model, plant_set)
    plant_values = np.r_[plant_set.classes + 1, 0].astype(np.uint8)  # index -1: background
    with torch.no_grad():

        def render(camera):
            view = plan.index(camera)
            image, alpha, meta = model.render([camera], plan.render_background)
            picture = plan.finish(view, image[0].numpy(), alpha[0, ..., 0].numpy())
            plants = plant_maps(camera, meta).label
            (out / PLANT_MAPS).mkdir(parents=True, exist_ok=True)
            write_image(out / PLANT_MAPS / f"view_{view:03d}.png", plant_values[plants])
            return outputs.to_uint8(picture), meta

        records = [{**r, "plant_path": f"{PLANT_MAPS}/view_{i:03d}.png"}
                   for i, r in enumerate(plan.records)]  # fmt: skip
        frames = render_views(model, writer, plan.cameras, render, records)
    outputs.write_renders(out / "renders", frames)
    oc = cfg.outputs
    outputs.write_turntables(out, frames, oc.turntable_frames if plan.turns else 0, oc.turntable)
    write_plant_exports(out)
    return len(frames)
