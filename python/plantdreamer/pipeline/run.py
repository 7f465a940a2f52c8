"""The generation loop: sample a camera, render, guide, step, densify, cull, checkpoint."""

from __future__ import annotations

import copy
import math
import os
import shutil
import sys
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from plantdreamer import _core
from plantdreamer.cameras import orbit_ring
from plantdreamer.errors import CheckpointError, InputError, PlantDreamerError
from plantdreamer.exports import write_plant_exports
from plantdreamer.exports.plant import LABEL_FILES
from plantdreamer.exports.points import class_comments
from plantdreamer.gaussians import Gaussians
from plantdreamer.guidance.base import Guidance
from plantdreamer.labels import check_mask_limits, class_counts
from plantdreamer.output_folder import claim_folder
from plantdreamer.pipeline import outputs
from plantdreamer.pipeline.checkpoint import CHECKPOINT_NAME, load_checkpoint, save_checkpoint
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.culling import large_gaussian_mask
from plantdreamer.pipeline.dataset_export import ground_truth_writer, render_views
from plantdreamer.pipeline.densify import DensifyStats, densify_and_prune
from plantdreamer.pipeline.depth_ahead import DepthAhead
from plantdreamer.pipeline.model import GaussianModel
from plantdreamer.pipeline.progress import Progress
from plantdreamer.pipeline.rerender import exported_scene
from plantdreamer.pipeline.sampler import CameraSampler
from plantdreamer.stop_signals import stop_signals_handled
from plantdreamer.versions import package_versions


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C during a run; a checkpoint at ``step`` was written before stopping."""

    def __init__(self, step: int, out_dir: Path) -> None:
        super().__init__(f"interrupted at step {step}")
        self.step, self.out_dir = step, out_dir


@dataclass
class RunResult:
    out_dir: Path
    ply_path: Path
    steps: int
    gaussians: int
    timings: dict[str, float]


class PhaseTimer:
    def __init__(self, totals: dict[str, float] | None = None) -> None:
        self.totals: dict[str, float] = defaultdict(float, totals or {})

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.totals[name] += time.perf_counter() - t0


def build_guidance(cfg: GenerateConfig) -> Guidance:
    """The guidance a config asks for; missing weights raise ModelNotFoundError here,
    before anything is written."""
    from plantdreamer.guidance.base import NoGuidance
    from plantdreamer.guidance.sds import StableDiffusionDepthGuidance

    if cfg.guidance == "none":
        return NoGuidance()
    return StableDiffusionDepthGuidance(
        base_model=cfg.base_model,
        controlnet=cfg.controlnet,
        lora=cfg.lora,
        species=cfg.plant_name(),
        guidance_scale=cfg.guidance_scale,
        conditioning_scale=cfg.conditioning_scale,
        schedule=cfg.schedule,
        total_steps=cfg.steps,
        seed=cfg.seed,
        resolution=cfg.sds_resolution,
        negative_prompt=cfg.negative_prompt,
        prompt_template=cfg.prompt_template or lora_template(cfg.lora),
        control_resize=cfg.control_resize,
        dtype=None if cfg.network_dtype == "auto" else cfg.network_dtype,
        vae_dtype=cfg.vae_dtype,
        device=cfg.device,
    )


def lora_template(lora: str | None) -> str:
    """The prompt template a LoRA recorded in its ``lora.json``, else the default."""
    from plantdreamer.guidance.config import DEFAULT_PROMPT_TEMPLATE
    from plantdreamer.guidance.lora_weights import recorded_template

    recorded = recorded_template(lora) if lora is not None else None
    return recorded or DEFAULT_PROMPT_TEMPLATE


def resolve_runtime(cfg: GenerateConfig) -> None:
    """Fills the settings decided by the machine or the inputs, so run.json and the
    checkpoints record the values used: the training resolution, the network precision and
    the prompt template (a LoRA's recorded template, else the default)."""
    # The networks' device (checked by check_inputs): CUDA when usable unless one is named.
    cuda = torch.cuda.is_available() if cfg.device is None else cfg.device.startswith("cuda")
    if cfg.resolution is None:
        cfg.resolution = 768 if cuda else 512
    if cfg.network_dtype == "auto":
        cfg.network_dtype = "float16" if cuda else "float32"
    if cfg.prompt_template is None:
        cfg.prompt_template = lora_template(cfg.lora)


# What a finished run writes at its end, the file that marks it finished first (deleted
# first by --overwrite; made anew by a resumed run).
FINAL_OUTPUTS = (
    "run.json",
    "plant.ply",
    "turntable.gif",
    "turntable.mp4",
    "renders",
    "labels",
    "instances",
    "depth",
    "transforms.json",
    *LABEL_FILES,
)
# Everything a run writes.
RUN_OUTPUTS = (*FINAL_OUTPUTS, "log.csv", CHECKPOINT_NAME)
# Settings a resumed run may change: more steps continue the same run further.
RESUME_CHANGEABLE = ("steps",)


def generate(
    cfg: GenerateConfig | None,
    out_dir: str | Path,
    *,
    guidance: Guidance | None = None,
    resume: bool = False,
    changes: dict[str, Any] | None = None,
    overwrite: bool = False,
    show_progress: bool = True,
    on_step: Callable[[int], None] | None = None,
    depth_ahead: bool = True,
) -> RunResult:
    """Runs (or resumes) a generation and writes every output into ``out_dir``.

    The folder is locked for the run. A new run needs an empty folder, or ``overwrite``,
    which deletes the previous run's outputs first (never a mix of two runs).
    With ``resume=True`` the config is the checkpoint's and ``cfg`` must be None;
    ``changes`` are settings given again on resume: equal ones are fine, more ``steps``
    continue the run further, any other difference is a CheckpointError.
    ``guidance`` overrides the one the config names (tests inject tiny models this way).
    The caller's ``cfg`` is not changed (the run works on a copy).
    Ctrl-C is honoured at the next step boundary: a checkpoint is written, then
    ``RunInterrupted`` is raised. ``depth_ahead`` computes the next step's depth
    conditioning on a worker thread (same bits; False computes it in line).
    """
    out_dir = Path(out_dir)
    if cfg is None and not resume:
        raise InputError("a config is needed unless resuming")
    if cfg is not None:
        check_inputs(cfg)
    if not resume and not overwrite and (out_dir / CHECKPOINT_NAME).is_file():
        raise InputError(
            f"{out_dir} holds a checkpoint of an earlier run; continue it with --resume "
            f"{out_dir}, pass --overwrite to start afresh, or choose another folder"
        )
    with claim_folder(
        out_dir, overwrite=overwrite and not resume, owned=RUN_OUTPUTS, allow_existing=resume
    ):
        state = note = None
        if resume:
            state = load_checkpoint(out_dir)
            cfg, note = _resumed_config(state, changes or {}, out_dir)
            check_inputs(cfg)
            for name in FINAL_OUTPUTS:  # a finished run's outputs are made anew
                path = out_dir / name
                if path.is_dir():
                    shutil.rmtree(path)
                else:
                    path.unlink(missing_ok=True)
        assert cfg is not None
        cfg = copy.deepcopy(cfg)  # the caller's config is not changed
        resolve_runtime(cfg)
        guidance = guidance if guidance is not None else build_guidance(cfg)
        run = _Run(cfg, out_dir, guidance, state, show_progress, on_step, depth_ahead)
        if note is not None:
            run.events.append(note)
        return run.run()


def _resumed_config(
    state: dict[str, Any], changes: dict[str, Any], out_dir: Path
) -> tuple[GenerateConfig, dict[str, Any] | None]:
    """The checkpoint's config with the allowed ``changes``, and an event recording them."""
    where = out_dir / CHECKPOINT_NAME
    try:
        cfg = GenerateConfig.from_dict(state["config"])
        cfg.validate()
        step = int(state["step"])
    except (KeyError, TypeError, ValueError, InputError) as exc:
        raise CheckpointError(f"{where}: damaged checkpoint, bad config ({exc})") from exc
    saved = {k: _setting(cfg, k) for k in changes}  # keys: "seed", "densify.start", ...
    differ = {k: v for k, v in changes.items() if saved[k] != v}
    refused = [
        f"{k}: checkpoint {saved[k]!r}, given {v!r}"
        for k, v in differ.items()
        if k not in RESUME_CHANGEABLE
    ]
    if refused:
        raise CheckpointError(
            f"--resume continues {out_dir} with the settings it started with, and these "
            f"differ: {'; '.join(refused)}. Only --steps may change (to continue further); "
            "start a new run (another --out, or --overwrite) to change the others"
        )
    if "steps" not in differ:
        return cfg, None
    if differ["steps"] < step:
        raise CheckpointError(
            f"--steps {differ['steps']} is below the checkpoint's step {step}; "
            "a resumed run can only go further"
        )
    note = {"step": step, "event": "steps changed", "from": cfg.steps, "to": differ["steps"]}
    cfg.steps = differ["steps"]
    return cfg, note


def _setting(cfg: GenerateConfig, key: str) -> Any:
    value: Any = cfg
    for name in key.split("."):
        if not hasattr(value, name):
            raise InputError(f"unknown setting {key!r}")
        value = getattr(value, name)
    return value


class _Run:
    def __init__(
        self,
        cfg: GenerateConfig,
        out_dir: Path,
        guidance: Guidance,
        state: dict[str, Any] | None,
        show_progress: bool,
        on_step: Callable[[int], None] | None,
        depth_ahead: bool = True,
    ) -> None:
        from plantdreamer.guidance.base import NoGuidance

        assert cfg.resolution is not None  # generate() decides it
        self.cfg, self.resolution, self.out_dir = cfg, cfg.resolution, out_dir
        self.guidance = guidance
        self.show_progress, self.on_step = show_progress, on_step
        self.trains = not isinstance(guidance, NoGuidance)
        if state is None:
            self._start_fresh()
        else:
            try:
                self._restore(state)
            except (KeyError, TypeError, ValueError, IndexError, RuntimeError) as exc:
                raise CheckpointError(
                    f"{out_dir / CHECKPOINT_NAME}: damaged or incompatible checkpoint "
                    f"({type(exc).__name__}: {exc})"
                ) from exc
        self.initial = GaussianModel(self.initial_gaussians)
        self._stop_requested = False
        self.depth_ahead = depth_ahead

    # -- setup -----------------------------------------------------------------------

    def _start_fresh(self) -> None:
        from plantdreamer.pipeline.source import initial_gaussians, load_source

        cfg = self.cfg
        self.timer = PhaseTimer()
        torch.manual_seed(cfg.seed)
        with self.timer("prepare"):
            source = load_source(cfg)
            g = initial_gaussians(cfg, source)
        if cfg.labels:  # the masks' limits, now rather than after the last step
            check_mask_limits(g.labels)
        self.transform, self.source_counts = source.transform, source.counts
        self.label_fields = source.label_fields if source.labels is not None else None
        if self.show_progress and cfg.pointcloud is not None:
            found = source.label_fields or {}
            print(
                f"labels: class from {found.get('label') or 'none'}, "
                f"instance from {found.get('instance') or 'none'}",
                file=sys.stderr,
            )
        self.initial_gaussians = g
        self.model = GaussianModel(g, cfg.lr)
        self.sampler = CameraSampler(cfg.cameras, self.resolution, cfg.seed, cfg.elevation_sampling)
        self.densify = DensifyStats.zeros(len(g))
        self.start_step = 0
        self.log_rows: list[dict[str, Any]] = []
        self.events: list[dict[str, Any]] = []

    def _restore(self, state: dict[str, Any]) -> None:
        self.timer = PhaseTimer(state["timings"])
        from plantdreamer.pointcloud import NormalizeTransform

        self.transform = NormalizeTransform.from_dict(state["transform"])
        self.source_counts = state["source_counts"]
        self.label_fields = state.get("label_fields")
        initial = {k: v.numpy() for k, v in state["initial"].items() if v is not None}
        self.initial_gaussians = Gaussians(**initial)
        self.model = GaussianModel(self.initial_gaussians, self.cfg.lr)
        self.model.load_state_dict(state["model"])
        self.sampler = CameraSampler(
            self.cfg.cameras, self.resolution, self.cfg.seed, self.cfg.elevation_sampling
        )
        self.sampler.set_state(state["sampler"])
        self.densify = DensifyStats(**state["densify"])
        self.start_step = state["step"]
        self.log_rows, self.events = state["log_rows"], state["events"]
        torch.set_rng_state(state["torch_rng"])
        if state.get("guidance") is not None:
            if self.guidance.generator is None:
                raise InputError("the checkpoint holds a guidance's noise state; this one has none")
            self.guidance.generator.set_state(state["guidance"])

    # -- the loop --------------------------------------------------------------------

    def run(self) -> RunResult:
        cfg = self.cfg
        conditioner = self._depth_conditioner() if self.guidance.needs_depth else None
        depth = None
        if conditioner is not None:
            depth = DepthAhead(conditioner, self.sampler.peek, self.depth_ahead)
        progress = Progress(cfg.steps, self.start_step, self.show_progress)
        progress.note(
            f"initialised {len(self.initial_gaussians)} Gaussians"
            + (
                ""
                if self.trains
                else "; no guidance: the steps only run density control and culling"
            )
        )
        try:
            with stop_signals_handled(self._request_stop):  # Ctrl-C, SIGTERM: checkpoint
                for step in range(self.start_step, cfg.steps):
                    if self._stop_requested:
                        self._checkpoint(step)
                        raise RunInterrupted(step, self.out_dir)
                    loss = self._train_step(step, depth) if self.trains else None
                    self._adapt_density(step)
                    progress.update(step, loss, len(self.model))
                    if (step + 1) % cfg.checkpoint_every == 0 and step + 1 < cfg.steps:
                        self._checkpoint(step + 1)
                    if self.on_step is not None:
                        self.on_step(step)
            progress.note(f"exporting {len(self.model)} Gaussians, {cfg.eval_views} renders")
        finally:
            progress.close()
            if depth is not None:
                depth.close()
        return self._finish()

    def _request_stop(self, signum, frame) -> None:
        if self._stop_requested:  # a second Ctrl-C or SIGTERM: stop now
            raise KeyboardInterrupt
        self._stop_requested = True

    def _train_step(self, step: int, conditioner: DepthAhead | None) -> float:
        cfg, model, timer = self.cfg, self.model, self.timer
        camera = self.sampler.sample()
        with timer("render"):
            image, _, meta = model.render([camera], cfg.background)
        depth = None
        if conditioner is not None:
            with timer("depth"):
                depth = conditioner.get(camera, more=step + 1 < cfg.steps)
        with timer("guidance"):
            out = self.guidance(image, depth, [camera], step)
        optimizer = model.optimizer
        assert optimizer is not None  # the model is built with learning rates
        with timer("backward"):
            optimizer.zero_grad(set_to_none=True)
            out.loss.backward()
        _check_finite_gradients(model, step)
        if step < cfg.densify.until and meta["means2d"].grad is not None:
            self.densify.update(meta["means2d"].grad, meta["radii"], camera.width, camera.height)
        with timer("optimizer"):
            optimizer.step()
        loss = float(out.loss.detach())
        if not math.isfinite(loss):
            raise PlantDreamerError(
                f"loss became {loss} at step {step}; stopping (no output written)"
            )
        self.log_rows.append({"step": step, "loss": loss, "gaussians": len(model), **out.stats})
        return loss

    def _adapt_density(self, step: int) -> None:
        cfg, dens, cull = self.cfg, self.cfg.densify, self.cfg.cull
        if dens.due(step):
            with self.timer("densify"):
                gen = torch.Generator().manual_seed(cfg.seed * 1_000_003 + step)
                before = self._class_counts()
                counts = densify_and_prune(
                    self.model,
                    self.densify,
                    dens.grad_threshold,
                    dens.split_scale,
                    dens.prune_opacity,
                    dens.max_gaussians,
                    gen,
                    dens.cap_rule,
                    dens.split_std,
                    dens.prune_screen_px,
                )
                self.densify = DensifyStats.zeros(len(self.model))
            event = {"step": step, "event": "densify", **counts, "gaussians": len(self.model)}
            if self.model.labels is not None:
                event["classes_before"], event["classes_after"] = before, self._class_counts()
            self.events.append(event)
        if cull.due(step):
            with self.timer("cull"):
                mask, stats = large_gaussian_mask(
                    self.model.params["log_scales"], cull.threshold, cull.volume
                )
                if stats["culled"]:
                    self.model.remove(mask)
                if stats["culled"] and step < dens.until:
                    self.densify = self.densify.subset(~mask)
            self.events.append(
                {"step": step, "event": "cull", **stats, "gaussians": len(self.model)}
            )

    def _class_names(self) -> dict[int, str] | None:
        if self.cfg.pointcloud is not None:
            return None
        from plantdreamer.lsystem import OrganClass

        return {int(c): c.name.lower() for c in OrganClass}

    def _label_summary(self, final: Gaussians) -> dict[str, Any] | None:
        """Where the labels came from and the Gaussians per class / instance count."""
        first, last = self.initial_gaussians.labels, final.labels
        if first is None or last is None:
            return None
        return {
            "fields": self.label_fields,
            "classes": {"initial": class_counts(first[:, 0]), "final": class_counts(last[:, 0])},
            "instances": {
                "initial": int(np.unique(first[first[:, 1] >= 0, 1]).size),
                "final": int(np.unique(last[last[:, 1] >= 0, 1]).size),
            },
            "exported": self.cfg.labels,
        }

    def _class_counts(self) -> dict[str, int]:
        labels = self.model.labels
        return {} if labels is None else class_counts(labels[:, 0].numpy())

    def _depth_conditioner(self):
        from plantdreamer.guidance.depth import DepthCleaning, DepthConditioner

        def render_depth(camera):
            with torch.no_grad():
                depth, alpha, _ = self.initial.render([camera], self.cfg.background, "ED")
            return depth, alpha

        size = self.guidance.resolution
        if size is None:
            raise InputError("a guidance that needs depth must say its resolution")
        cleaning = DepthCleaning(
            rule=self.cfg.depth_rule,
            resize=self.cfg.control_resize,
            distance=self.cfg.erosion_distance,
        )
        return DepthConditioner(render_depth, out_size=size, config=cleaning)

    # -- persistence -------------------------------------------------------------------

    def _checkpoint(self, step: int) -> None:
        with self.timer("checkpoint"):
            g = self.initial_gaussians
            save_checkpoint(
                self.out_dir,
                {
                    "step": step,
                    "config": self.cfg.to_dict(),
                    "model": self.model.state_dict(),
                    "initial": {
                        k: None if getattr(g, k) is None else torch.from_numpy(getattr(g, k).copy())
                        for k in ("means", "quats", "log_scales", "opacity_logits", "sh", "labels")
                    },
                    "transform": self.transform.to_dict(),
                    "source_counts": self.source_counts,
                    "label_fields": self.label_fields,
                    "sampler": self.sampler.state(),
                    "densify": {
                        "grad_sum": self.densify.grad_sum,
                        "count": self.densify.count,
                        "max_radius": self.densify.max_radius,
                    },
                    "torch_rng": torch.get_rng_state(),
                    # The guidance's noise generator, so a resumed run draws the same noise.
                    "guidance": _generator_state(self.guidance),
                    "log_rows": self.log_rows,
                    "events": self.events,
                    "timings": dict(self.timer.totals),
                },
            )
            outputs.write_log_csv(self.out_dir / "log.csv", self.log_rows)

    def _finish(self) -> RunResult:
        cfg, out = self.cfg, self.out_dir
        final = self.model.to_gaussians()
        with self.timer("export"):
            ply_path = out / "plant.ply"
            offset = outputs.export_offset(self.transform, cfg.scene_size)
            self.export_offset = None if offset is None else [float(v) for v in offset]
            comments: tuple[str, ...] = ()
            if offset is not None:
                comments = (outputs.offset_comment(offset),)
            comments += class_comments(self._class_names()) if cfg.labels else ()
            exported = outputs.to_input_frame(final, self.transform, offset)
            outputs.export_ply(ply_path, exported, cfg.sh_degree_export, cfg.labels, comments)
            # Views and ground truth of what plant.ply holds (positions as float32 in the
            # input frame, its SH degree), so `render` remakes them exactly.
            if cfg.sh_degree_export is not None:
                exported = exported.with_sh_degree(cfg.sh_degree_export)
            view_model = GaussianModel(exported_scene(exported, self.transform, offset))
        with self.timer("renders"), torch.no_grad():
            # Each view's render, then its ground truth (which reuses the render's footprints).
            cameras = orbit_ring(
                cfg.eval_views,
                cfg.eval_distance,
                cfg.eval_elevation_deg,
                cfg.eval_fovy_deg,
                self.resolution,
                self.resolution,
            )
            writer = ground_truth_writer(
                out, view_model, self.transform, cfg.labels, self._class_names()
            )

            def render(camera):
                image, _, meta = view_model.render([camera], cfg.background)
                return outputs.to_uint8(image[0].numpy()), meta

            frames = render_views(view_model, writer, cameras, render)
            outputs.write_renders(out / "renders", frames)
            outputs.write_turntables(out, frames, cfg.turntable_frames, cfg.turntable)
        outputs.write_log_csv(out / "log.csv", self.log_rows)
        with self.timer("label files"):
            write_plant_exports(out)
        outputs.write_json(out / "run.json", self._summary(final))
        return RunResult(out, ply_path, cfg.steps, len(final), dict(self.timer.totals))

    def _summary(self, final: Gaussians) -> dict[str, Any]:
        steps_trained = len(self.log_rows)
        per_step = {
            k: v / steps_trained
            for k, v in self.timer.totals.items()
            if steps_trained and k in ("render", "depth", "guidance", "backward", "optimizer")
        }
        return {
            "config": self.cfg.to_dict(),
            "seed": self.cfg.seed,
            "versions": package_versions(),
            "threads": torch.get_num_threads(),
            "cpu_count": os.cpu_count(),
            "device": str(getattr(self.guidance, "device", "cpu")),
            "raster_threads": _core.info()["threads"],
            "source_points": self.source_counts,
            "gaussians": {"initial": len(self.initial_gaussians), "final": len(final)},
            "labels": self._label_summary(final),
            "class_names": self._class_names() if self.cfg.labels else None,
            "timings_s": dict(self.timer.totals),
            "per_step_s": per_step,
            "events": self.events,
            "transform": self.transform.to_dict(),
            # plant.ply holds positions minus this offset (None: the input frame itself).
            "export_offset": self.export_offset,
        }


def _check_finite_gradients(model: GaussianModel, step: int) -> None:
    """Stops before a NaN or Inf gradient reaches the Gaussians through Adam (whose moments
    it would poison for every later step)."""
    for name, p in model.params.items():
        # A finite sum proves every value finite (one reduction, no mask); only a non-finite
        # one (a bad value, or rarely an overflowing sum) runs the exact test.
        if p.grad is None or math.isfinite(float(p.grad.sum())):
            continue
        if not bool(torch.isfinite(p.grad).all()):
            bad = int((~torch.isfinite(p.grad)).sum())
            raise PlantDreamerError(
                f"non-finite gradient on the Gaussians' {name} ({bad} values) at step {step}; "
                "stopping (no output written)"
            )


def _generator_state(guidance: Guidance) -> torch.Tensor | None:
    generator = guidance.generator
    return None if generator is None else generator.get_state()


def check_inputs(cfg: GenerateConfig) -> None:
    """Fails fast on inputs that cannot work, before any model is loaded."""
    cfg.validate()
    if cfg.guidance != "none":
        from plantdreamer.guidance.models import resolve_device

        resolve_device(cfg.device)
    if cfg.pointcloud is not None and not Path(cfg.pointcloud).is_file():
        raise FileNotFoundError(f"point cloud not found: {cfg.pointcloud}")
    if cfg.pointcloud is None:
        from plantdreamer.lsystem import list_species

        if cfg.structure() not in list_species():
            raise InputError(f"unknown species {cfg.species!r}; known: {', '.join(list_species())}")
