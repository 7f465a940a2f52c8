"""The generation loop: sample a camera, render, guide, step, densify, cull, checkpoint."""

from __future__ import annotations

import copy
import math
import os
import signal
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
from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.gaussians import Gaussians
from plantdreamer.guidance.base import Guidance
from plantdreamer.pipeline import outputs
from plantdreamer.pipeline.checkpoint import load_checkpoint, save_checkpoint
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.culling import large_gaussian_mask
from plantdreamer.pipeline.densify import DensifyStats, densify_and_prune
from plantdreamer.pipeline.depth_ahead import DepthAhead
from plantdreamer.pipeline.init import init_gaussians, initial_colors
from plantdreamer.pipeline.model import GaussianModel
from plantdreamer.pipeline.progress import Progress
from plantdreamer.pipeline.sampler import CameraSampler
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


def default_resolution() -> int:
    return 768 if torch.cuda.is_available() else 512


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
        species=cfg.species or "plant",
        guidance_scale=cfg.guidance_scale,
        conditioning_scale=cfg.conditioning_scale,
        schedule=cfg.schedule,
        total_steps=cfg.steps,
        seed=cfg.seed,
        resolution=cfg.sds_resolution,
        device=cfg.device,
    )


def generate(
    cfg: GenerateConfig | None,
    out_dir: str | Path,
    *,
    guidance: Guidance | None = None,
    resume: bool = False,
    show_progress: bool = True,
    on_step: Callable[[int], None] | None = None,
    depth_ahead: bool = True,
) -> RunResult:
    """Runs (or resumes) a generation and writes every output into ``out_dir``.

    With ``resume=True`` the config is the checkpoint's and ``cfg`` must be None.
    ``guidance`` overrides the one the config names (tests inject tiny models this way).
    The caller's ``cfg`` is not changed (the run works on a copy).
    Ctrl-C is honoured at the next step boundary: a checkpoint is written, then
    ``RunInterrupted`` is raised. ``depth_ahead`` computes the next step's depth
    conditioning on a worker thread (same bits; False computes it in line).
    """
    out_dir = Path(out_dir)
    state = load_checkpoint(out_dir) if resume else None
    if state is not None:
        cfg = GenerateConfig.from_dict(state["config"])
    if cfg is None:
        raise InputError("a config is needed unless resuming")
    check_inputs(cfg)
    _check_writable(out_dir)
    cfg = copy.deepcopy(cfg)
    if cfg.resolution is None:
        cfg.resolution = default_resolution()
    guidance = guidance if guidance is not None else build_guidance(cfg)
    return _Run(cfg, out_dir, guidance, state, show_progress, on_step, depth_ahead).run()


def _check_writable(out_dir: Path) -> None:
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        probe = out_dir / ".write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise PermissionError(f"output folder {out_dir} is not writable: {exc}") from exc


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
            self._restore(state)
        self.initial = GaussianModel(self.initial_gaussians)
        self._stop_requested = False
        self.depth_ahead = depth_ahead

    # -- setup -----------------------------------------------------------------------

    def _start_fresh(self) -> None:
        from plantdreamer.pipeline.source import load_source

        cfg = self.cfg
        self.timer = PhaseTimer()
        torch.manual_seed(cfg.seed)
        with self.timer("prepare"):
            source = load_source(cfg)
            rng = np.random.default_rng([cfg.seed, 0xC0102])
            colors = initial_colors(source.colors, len(source.points), cfg.color_init, rng)
            g = init_gaussians(source.points, colors, cfg.initial_opacity(), cfg.sh_degree)
        self.transform, self.source_counts = source.transform, source.counts
        self.initial_gaussians = g
        self.model = GaussianModel(g, cfg.lr)
        self.sampler = CameraSampler(cfg.cameras, self.resolution, cfg.seed)
        self.densify = DensifyStats.zeros(len(g))
        self.start_step = 0
        self.log_rows: list[dict[str, Any]] = []
        self.events: list[dict[str, Any]] = []

    def _restore(self, state: dict[str, Any]) -> None:
        self.timer = PhaseTimer(state["timings"])
        from plantdreamer.pointcloud import NormalizeTransform

        self.transform = NormalizeTransform.from_dict(state["transform"])
        self.source_counts = state["source_counts"]
        self.initial_gaussians = Gaussians(**{k: v.numpy() for k, v in state["initial"].items()})
        self.model = GaussianModel(self.initial_gaussians, self.cfg.lr)
        self.model.load_state_dict(state["model"])
        self.sampler = CameraSampler(self.cfg.cameras, self.resolution, self.cfg.seed)
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
        previous = signal.getsignal(signal.SIGINT)
        signal.signal(signal.SIGINT, self._request_stop)
        try:
            for step in range(self.start_step, cfg.steps):
                if self._stop_requested:
                    self._checkpoint(step)
                    raise RunInterrupted(step, self.out_dir)
                loss = self._train_step(step, depth) if self.trains else 0.0
                self._adapt_density(step)
                progress.update(step, loss, len(self.model))
                if (step + 1) % cfg.checkpoint_every == 0 and step + 1 < cfg.steps:
                    self._checkpoint(step + 1)
                if self.on_step is not None:
                    self.on_step(step)
        finally:
            signal.signal(signal.SIGINT, previous)
            progress.close()
            if depth is not None:
                depth.close()
        return self._finish()

    def _request_stop(self, signum, frame) -> None:
        if self._stop_requested:  # second Ctrl-C: stop now
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
                counts = densify_and_prune(
                    self.model,
                    self.densify,
                    dens.grad_threshold,
                    dens.split_scale,
                    dens.prune_opacity,
                    dens.max_gaussians,
                    gen,
                )
                self.densify = DensifyStats.zeros(len(self.model))
            self.events.append(
                {"step": step, "event": "densify", **counts, "gaussians": len(self.model)}
            )
        if cull.due(step):
            with self.timer("cull"):
                mask, stats = large_gaussian_mask(self.model.params["log_scales"], cull.threshold)
                if stats["culled"]:
                    self.model.remove(mask)
                if stats["culled"] and step < dens.until:
                    self.densify = DensifyStats(
                        self.densify.grad_sum[~mask], self.densify.count[~mask]
                    )
            self.events.append(
                {"step": step, "event": "cull", **stats, "gaussians": len(self.model)}
            )

    def _depth_conditioner(self):
        from plantdreamer.guidance.depth import DepthConditioner

        def render_depth(camera):
            with torch.no_grad():
                depth, alpha, _ = self.initial.render([camera], self.cfg.background, "ED")
            return depth, alpha

        size = self.guidance.resolution
        if size is None:
            raise InputError("a guidance that needs depth must say its resolution")
        return DepthConditioner(render_depth, out_size=size)

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
                        k: torch.from_numpy(getattr(g, k).copy())
                        for k in ("means", "quats", "log_scales", "opacity_logits", "sh")
                    },
                    "transform": self.transform.to_dict(),
                    "source_counts": self.source_counts,
                    "sampler": self.sampler.state(),
                    "densify": {"grad_sum": self.densify.grad_sum, "count": self.densify.count},
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
            outputs.export_ply(
                ply_path, outputs.to_input_frame(final, self.transform), cfg.sh_degree_export
            )
        with self.timer("renders"), torch.no_grad():
            frames = outputs.render_orbit(
                lambda cam: self.model.render([cam], cfg.background)[0][0].numpy(),
                cfg.eval_views,
                cfg.eval_distance,
                cfg.eval_elevation_deg,
                cfg.eval_fovy_deg,
                self.resolution,
            )
            outputs.write_renders(out / "renders", frames)
            outputs.write_turntable(out / "turntable.gif", frames, cfg.turntable_frames)
        outputs.write_log_csv(out / "log.csv", self.log_rows)
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
            "timings_s": dict(self.timer.totals),
            "per_step_s": per_step,
            "events": self.events,
            "transform": self.transform.to_dict(),
        }


def _check_finite_gradients(model: GaussianModel, step: int) -> None:
    """Stops before a NaN or Inf gradient reaches the Gaussians through Adam (whose moments
    it would poison for every later step)."""
    for name, p in model.params.items():
        if p.grad is not None and not bool(torch.isfinite(p.grad).all()):
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

        if cfg.species not in list_species():
            raise InputError(f"unknown species {cfg.species!r}; known: {', '.join(list_species())}")
