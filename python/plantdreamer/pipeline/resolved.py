"""The fully resolved settings of a run, as ``plantdreamer generate --print-config`` shows them.

A run's config after its preset, the user's options and the runtime fills (a LoRA's recorded
prompt template, the resolution and precision of this machine), plus what those settings
turn into: the species structure grown, the prompts as the text encoder receives them, the
timestep range of each phase and the steps where density control and culling run. Users
check a run here before spending GPU hours on it; tests check the presets through it.
"""

from __future__ import annotations

from typing import Any

from plantdreamer.pipeline.config import GenerateConfig

NUM_TRAIN_TIMESTEPS = 1000  # Stable Diffusion's scheduler (integer timesteps shown for it)


def resolved_settings(cfg: GenerateConfig) -> dict[str, Any]:
    """Validates ``cfg``, fills its runtime settings (as the run would) and returns a
    JSON-ready description of the run. Loads no model."""
    from plantdreamer.guidance.prompts import VIEWS, base_prompt
    from plantdreamer.guidance.schedules import make_schedule
    from plantdreamer.pipeline.runtime import check_inputs, resolve_runtime

    check_inputs(cfg)
    resolve_runtime(cfg)
    out: dict[str, Any] = {
        "config": cfg.to_dict(),
        "structure": None if cfg.source.pointcloud is not None else cfg.source.structure(),
        "densify_steps": [s for s in range(cfg.train.steps) if cfg.density.densify.due(s)],
        "cull_steps": [s for s in range(cfg.train.steps) if cfg.density.cull.due(s)],
    }
    if cfg.sds.guidance == "none":
        return {**out, "prompts": None, "negative_prompt": None, "timesteps": None}
    assert cfg.sds.prompt_template is not None  # resolve_runtime filled it
    prompt = base_prompt(cfg.source.plant_name(), cfg.sds.prompt_template)
    out["prompts"] = {view: f"{prompt}, {view} view" for view in VIEWS}
    out["negative_prompt"] = cfg.sds.negative_prompt
    out["timesteps"] = _phases(make_schedule(cfg.sds.schedule, cfg.train.steps), cfg.train.steps)
    return out


def _phases(schedule: Any, steps: int) -> list[dict[str, Any]]:
    """Each stage of the schedule that the run reaches: its steps and timestep range."""
    phases, start = [], 0
    for stage in schedule.stages:
        end = steps if stage.until_step is None else min(stage.until_step, steps)
        if start >= end:
            break
        phases.append(
            {
                "steps": [start, end - 1],
                "t_fraction": [stage.min_frac, stage.max_frac],
                "t": list(schedule.bounds(start, NUM_TRAIN_TIMESTEPS)),
            }
        )
        start = end
    return phases
