"""What a finished run writes: plant.ply in the input's frame, the evaluation renders with
their ground truth, the turntable, log.csv and run.json (written last: it marks the run
finished). The run's periodic checkpoint is removed once everything else is written."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from plantdreamer import _core
from plantdreamer.errors import InputError
from plantdreamer.exports import write_plant_exports
from plantdreamer.exports.points import class_comments
from plantdreamer.gaussians import Gaussians
from plantdreamer.guidance.model_files import run_models
from plantdreamer.pipeline import outputs
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.progress import Counter
from plantdreamer.pipeline.rerender import exported_scene
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pipeline.state.checkpoint import CHECKPOINT_NAME
from plantdreamer.pipeline.state.run_state import RunState
from plantdreamer.pipeline.truth.dataset_export import ground_truth_writer, render_views
from plantdreamer.traits import TRAITS_FILE, write_traits
from plantdreamer.traits.record import run_traits, view_recorder
from plantdreamer.versions import package_versions
from plantdreamer.views import ViewPlan, plan_views

# Per-step phases reported in run.json's per_step_s, each with one meaning: the native
# render of the plants, the depth maps taken, the guidance's launch (networks queued, or
# run on the CPU), its backward to the renders, the host's wait for the device, the
# rasterizer's backward past the renders, and the checks and Adam (docs/step.md). A plant
# of a group records its share of each: the group's plants sum to the group's time.
STEP_PHASES = (
    "raster.forward", "depth", "guidance.launch", "guidance.backward", "guidance.wait",
    "raster.backward", "optimizer",
)  # fmt: skip


@dataclass
class RunResult:
    out_dir: Path
    ply_path: Path
    steps: int
    gaussians: int
    timings: dict[str, float]


def export_run(
    cfg: GenerateConfig,
    state: RunState,
    out: Path,
    device: str,
    show_progress: bool = False,
    stop_point: Callable[[], None] | None = None,
) -> RunResult:
    """Writes every output of a finished run into ``out`` (``show_progress``: a count of
    the views rendered, then a line before the label files); a model that training left
    without Gaussians is refused before anything is written. ``stop_point`` raises when a
    stop was asked for (``Trainer.stop_point``): called before each view and before the
    label files, so a stop during the export ends it within one view (the final
    checkpoint is written: a resume redoes the export)."""
    final = state.model.to_gaussians()
    if len(final) == 0:
        emptied = next((e for e in state.events if e.get("gaussians") == 0), None)
        when = f" (the {emptied['event']} round of step {emptied['step']})" if emptied else ""
        raise InputError(
            f"no Gaussian is left to export: training removed all {len(state.initial)}"
            f"{when}; check the densify and cull settings"
        )
    timer, oc = state.timer, cfg.outputs
    class_names = _class_names(cfg)
    with timer("export"):
        ply_path = out / "plant.ply"
        offset = outputs.export_offset(state.transform, cfg.source.scene_size)
        export_offset = None if offset is None else [float(v) for v in offset]
        comments: tuple[str, ...] = ()
        if offset is not None:
            comments = (outputs.offset_comment(offset),)
        comments += class_comments(class_names) if oc.labels else ()
        exported = state.transform.gaussians_to_original(final, offset)
        outputs.export_ply(ply_path, exported, oc.sh_degree_export, oc.labels, comments)
        # Views and ground truth of what plant.ply holds (positions as float32 in the
        # input frame, its SH degree), so `render` remakes them exactly.
        if oc.sh_degree_export is not None:
            exported = exported.with_sh_degree(oc.sh_degree_export)
        scene = exported_scene(exported, state.transform, offset)
        view_model = GaussianModel(scene)
    with timer("renders"), torch.no_grad():
        # Each view's render, then its ground truth (which reuses the render's footprints),
        # on the orbit framed on what plant.ply holds unless the distance is given.
        plan = export_plan(cfg, scene)  # the orbit, or the rig; backgrounds, jitter
        cameras, eval_distance = plan.cameras, plan.orbit_distance
        writer = ground_truth_writer(out, view_model, state.transform, oc.labels, class_names)
        labels = None if view_model.labels is None else view_model.labels.numpy()
        recorder = view_recorder(
            view_model.params["means"].detach().numpy(),
            labels, class_names, state.transform.scale, oc.leaf_occlusion,
        )  # fmt: skip

        turntable_frames = oc.turntable_frames if plan.turns else 0  # no turntable of a rig
        views = outputs.StreamedViews(
            out / "renders", len(cameras), turntable_frames, oc.turntable, plan.png
        )  # each view written as it is made
        with Counter("export: views", len(cameras), show_progress) as counter:

            def render(camera):
                if stop_point is not None:  # a stop asked for: within one view
                    stop_point()
                image, alpha, meta = view_model.render([camera], plan.render_background)
                counter.advance()
                picture = plan.finish(
                    plan.index(camera), image[0].numpy(), alpha[0, ..., 0].numpy()
                )
                return outputs.to_uint8(picture), meta

            render_views(view_model, writer, cameras, render, views.add, plan.records,
                         observe=recorder.add)  # fmt: skip
        views.write_turntables(out)
    outputs.write_log_csv(out / "log.csv", state.log_rows)
    if stop_point is not None:
        stop_point()
    with timer("traits"):  # the L-System grown again, or the scan's points (traits/)
        src, invert, start = cfg.source, state.transform.invert, state.initial
        species = src.structure() if src.pointcloud is None else None
        record = run_traits(species, cfg.seed, src.growth, src.growth_since,
                            (invert(start.means.astype(np.float64)), start.labels),
                            (invert(final.means.astype(np.float64)), final.labels),
                            class_names, recorder)  # fmt: skip
        write_traits(out / TRAITS_FILE, record)
    if show_progress:
        print("export: label files (COCO, YOLO-seg, points.ply)", file=sys.stderr, flush=True)
    with timer("label files"):
        write_plant_exports(out)
    summary = _summary(cfg, state, final, device, export_offset)
    # What the export decided: the orbit's distance (framed on plant.ply, or given).
    summary["outputs"] = {"eval_distance": eval_distance}
    outputs.write_json(out / "run.json", summary)
    (out / CHECKPOINT_NAME).unlink(missing_ok=True)  # finished: nothing left to resume
    return RunResult(out, ply_path, cfg.train.steps, len(final), dict(timer.totals))


def export_plan(cfg: GenerateConfig, scene: Gaussians) -> ViewPlan:
    """The exported views of ``scene`` (the scene frame): ``views.plan_views`` with the
    run's orbit, seed, render size and grey."""
    oc, size = cfg.outputs, cfg.train.render_size
    return plan_views(
        oc.views, scene, cfg.seed, oc.eval_views, oc.eval_fovy_deg, size, cfg.train.background,
        orbit=lambda: outputs.eval_orbit(oc, scene, size),
    )  # fmt: skip


def _class_names(cfg: GenerateConfig) -> dict[int, str] | None:
    if cfg.source.pointcloud is not None:
        return None
    from plantdreamer.lsystem import OrganClass

    return {int(c): c.name.lower() for c in OrganClass}


def _summary(
    cfg: GenerateConfig,
    state: RunState,
    final: Gaussians,
    device: str,
    export_offset: list[float] | None,
) -> dict[str, Any]:
    totals = state.timer.totals
    steps_trained = len(state.log_rows)
    per_step = {
        k: v / steps_trained for k, v in totals.items() if steps_trained and k in STEP_PHASES
    }
    return {
        "config": cfg.to_dict(),
        "versions": package_versions(),
        "models": run_models(cfg.sds),  # each model file read, with its SHA-256
        "threads": torch.get_num_threads(),
        "cpu_count": os.cpu_count(),
        "device": device,
        "raster_threads": _core.info()["threads"],
        "source_points": state.source_counts,
        "gaussians": {"initial": len(state.initial), "final": len(final)},
        "labels": state.label_summary(final, cfg.outputs.labels),
        "class_names": _class_names(cfg) if cfg.outputs.labels else None,
        "timings_s": dict(totals),
        "per_step_s": per_step,
        "events": state.events,
        "transform": state.transform.to_dict(),
        # plant.ply holds positions minus this offset (None: the input frame itself).
        "export_offset": export_offset,
    }
