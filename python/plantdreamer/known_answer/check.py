"""The known-answer check: the real ``generate`` from wrong colours, scored against the truth.

Each run is ``plantdreamer generate`` through its Python entry point, with the known-answer
models loaded by the real loader (``base_model`` / ``controlnet`` folders). Scores are
``plantdreamer eval``'s masked PSNR (its ``evaluate``) on held-out true views. A step curve
is made of separate runs of increasing length: the timestep schedule is given as an explicit
table (the built-in one scaled to the longest run), so a shorter run is exactly the first
steps of a longer one.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plantdreamer.errors import InputError
from plantdreamer.eval.frames import Frame
from plantdreamer.gaussians import Gaussians
from plantdreamer.known_answer import views
from plantdreamer.known_answer.build import model_dirs
from plantdreamer.known_answer.denoiser import denoiser_check, unseen_views
from plantdreamer.known_answer.spec import CHECK_STEPS, KnownAnswerSpec
from plantdreamer.known_answer.timesteps import run_timesteps

# Companions' seeds are the plant's plus multiples of this (no model set is made for them).
COMPANION_SEED_OFFSET = 1000


def schedule_table(name: str, steps: int) -> str:
    """The built-in schedule ``name`` as ``steps`` long a run uses it, written as a table."""
    from plantdreamer.guidance.schedules import make_schedule

    stages = make_schedule(name, max(steps, 1)).stages
    return ",".join(
        f"{s.min_frac!r}-{s.max_frac!r}" + ("" if s.until_step is None else f"@{s.until_step}")
        for s in stages
    )


@dataclass
class RunScore:
    steps: int
    masked_psnr: float
    seconds: float
    gaussians: int


@dataclass
class Truth:
    """The plant's true Gaussians and its held-out views."""

    gaussians: Gaussians
    frames: list[Frame] = field(default_factory=list)

    @classmethod
    def of(cls, spec: KnownAnswerSpec, work_dir: Path) -> Truth:
        gaussians = views.true_gaussians(spec, work_dir)
        return cls(gaussians, views.held_out_frames(spec, gaussians))

    def score(self, ply: Path) -> float:
        """Masked PSNR of a run's ``plant.ply`` (beside its ``run.json``), in the scene frame
        the held-out views are made in."""
        from plantdreamer.eval import evaluate
        from plantdreamer.io import read_splat_ply

        plant = views.in_generate_frame(read_splat_ply(ply), ply)
        result = evaluate(plant, self.frames, keep_views=0)
        value = result.mean["masked_psnr"]
        assert value is not None  # every held-out view has a mask
        return float(value)


def companion_seeds(spec: KnownAnswerSpec, group: int) -> list[int]:
    """The seeds trained beside the scored plant in a group of ``group``: other plants of
    the species, far from the seeds known-answer models are made for."""
    return [spec.seed + COMPANION_SEED_OFFSET * k for k in range(1, group)]


def run_generate(
    spec: KnownAnswerSpec,
    models: Path | None,
    out: Path,
    steps: int,
    schedule: str,
    group: int = 1,
    **settings: Any,
) -> tuple[Path, float, int]:
    """One ``generate`` run; (plant.ply, seconds, Gaussians). ``models=None``: no guidance.
    ``group`` > 1: the plant is trained first in a group (``generate --seeds``) with
    ``group - 1`` companions guided by the same models; only the plant is returned."""
    from plantdreamer.pipeline import FolderPerPlant, generate_plants
    from plantdreamer.pipeline.runs.record import plant_name

    if models is None:
        settings = {"guidance": "none", **settings}
    else:
        base, control = model_dirs(models)
        settings = {"base_model": str(base), "controlnet": str(control), **settings}
    cfg = views.generate_config(spec, steps=steps, schedule=schedule, **settings)
    t0 = time.perf_counter()
    if group <= 1 or models is None:
        result = generate_plants([cfg], out, overwrite=True, show_progress=False)[0]
        return Path(result.ply_path), time.perf_counter() - t0, int(result.gaussians)
    cfgs = [cfg] + [
        views.generate_config(spec, steps=steps, schedule=schedule, seed=s, **settings)
        for s in companion_seeds(spec, group)
    ]
    results = generate_plants(cfgs, out, layout=FolderPerPlant(), overwrite=True,
                              show_progress=False)  # fmt: skip
    seconds = time.perf_counter() - t0
    plant = next(r for r in results if r.name == plant_name(cfg))
    return Path(plant.ply_path), seconds, int(plant.gaussians)


def step_curve(
    spec: KnownAnswerSpec,
    truth: Truth,
    models: Path,
    work_dir: Path,
    curve: Sequence[int],
    schedule_name: str = "paper",
    **settings: Any,
) -> list[RunScore]:
    """Masked PSNR after each number of steps in ``curve`` (0 = the initial Gaussians)."""
    table = schedule_table(schedule_name, max(curve))
    scores = []
    for steps in sorted(set(curve)):
        ply, seconds, count = run_generate(
            spec,
            models if steps else None,
            work_dir / f"run_{steps}",
            steps,
            table,
            **settings,
        )
        scores.append(RunScore(steps, truth.score(ply), seconds, count))
    return scores


def known_answer(
    spec: KnownAnswerSpec,
    trained: Path,
    untrained: Path,
    work_dir: Path,
    steps: int = CHECK_STEPS,
    curve: Sequence[int] = (),
    with_true_colours: bool = True,
    device: str = "cpu",
    **settings: Any,
) -> dict[str, Any]:
    """The check's figures: from noise colours with the trained and the untrained models, and
    (``with_true_colours``) from the true colours with the trained ones. ``device`` runs
    the guidance there (``cuda``: precision, batching and overlap judged on CUDA); the
    rasterizer and the true plant stay on the CPU."""
    check_device(device)
    if device != "cpu":
        settings = {**settings, "device": device}
    truth = Truth.of(spec, work_dir)
    points = sorted({0, steps, *curve})
    noise = {"color_init": "noise", **settings}
    trained_curve = step_curve(spec, truth, trained, work_dir / "trained", points, **noise)
    control = step_curve(spec, truth, untrained, work_dir / "control", [steps], **noise)
    out: dict[str, Any] = {
        "spec": spec.to_dict(),
        "steps": steps,
        "settings": {k: v for k, v in settings.items()},
        "psnr_init": trained_curve[0].masked_psnr,
        "psnr_final": trained_curve[-1].masked_psnr,
        "psnr_control_final": control[0].masked_psnr,
        "seconds": trained_curve[-1].seconds,
        "gaussians_final": trained_curve[-1].gaussians,
        "curve": [vars(s) for s in trained_curve],
    }
    if steps:
        run_dir = work_dir / "trained" / f"run_{steps}"
        # A group's plants each log their own draws: every one of them is checked.
        logs = sorted(run_dir.glob("*/log.csv")) if settings.get("group", 1) > 1 else []
        out.update(run_timesteps(logs or [run_dir / "log.csv"], steps))
    unseen = unseen_views(spec, truth.gaussians)
    denoised = denoiser_check(trained, spec, unseen, steps, device)
    denoised.pop("timesteps")
    out.update(denoised)
    out["x0_error_control"] = denoiser_check(untrained, spec, unseen, steps, device)["x0_error"]
    if with_true_colours:
        true = {"color_init": "original", **settings}
        runs = step_curve(spec, truth, trained, work_dir / "true", [0, steps], **true)
        out["psnr_true_init"] = runs[0].masked_psnr
        out["psnr_true_final"] = runs[-1].masked_psnr
    return out


def check_device(device: str) -> None:
    """``cpu`` or an available ``cuda[:N]``; anything else is one clear InputError."""
    import torch

    if device == "cpu":
        return
    if device.split(":")[0] != "cuda":
        raise InputError(f"device must be cpu or cuda (cuda:N), got {device!r}")
    if not torch.cuda.is_available():
        raise InputError(f"device {device!r} asked for, but torch sees no CUDA GPU")
