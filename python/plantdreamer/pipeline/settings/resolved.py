"""The fully resolved settings of a run, as ``plantdreamer generate --print-config`` shows them.

Each plant's config after its preset, the user's options and the settings the run decides
(``runtime.resolve_plants``, the one function the run calls too: a LoRA's recorded prompt
template, the resolution and precision of this machine, overlap for the plant count), so
its ``config`` is what run.json records; plus what those settings turn into: the species
structure grown, the prompts as the text encoder receives them, the timestep range of each
phase and the steps where density control and culling run (as progressions: first, last,
every and count). Users check a run here before spending GPU hours on it; tests check the
presets through it.
"""

from __future__ import annotations

import copy
from typing import Any

from plantdreamer.pipeline.settings.config import GenerateConfig

NUM_TRAIN_TIMESTEPS = 1000  # Stable Diffusion's scheduler (integer timesteps shown for it)


def resolved_settings(cfgs: list[GenerateConfig]) -> list[dict[str, Any]]:
    """Validates the configs of plants trained together, decides their open settings as the
    run would and returns a JSON-ready description of each plant's run (one plant: a list
    of one). Loads no model; the callers' configs are not changed."""
    from plantdreamer.pipeline.settings.config import check_shared
    from plantdreamer.pipeline.settings.runtime import check_inputs, resolve_plants

    cfgs = [copy.deepcopy(c) for c in cfgs]
    for cfg in cfgs:
        check_inputs(cfg)
    check_shared(cfgs)
    resolve_plants(cfgs)
    return [_described(cfg) for cfg in cfgs]


def _described(cfg: GenerateConfig) -> dict[str, Any]:
    from plantdreamer.guidance.prompts import VIEWS, base_prompt
    from plantdreamer.guidance.schedules import make_schedule

    out: dict[str, Any] = {
        "config": cfg.to_dict(),
        "structure": None if cfg.source.pointcloud is not None else cfg.source.structure(),
        "densify_steps": densify_steps(cfg),
        "cull_steps": cull_steps(cfg),
    }
    if cfg.sds.guidance == "none":
        return {**out, "prompts": None, "negative_prompt": None, "timesteps": None}
    assert cfg.sds.prompt_template is not None  # resolve_plants filled it
    prompt = base_prompt(cfg.source.plant_name(), cfg.sds.prompt_template)
    out["prompts"] = {view: f"{prompt}, {view} view" for view in VIEWS}
    out["negative_prompt"] = cfg.sds.negative_prompt
    out["timesteps"] = _phases(make_schedule(cfg.sds.schedule, cfg.train.steps), cfg.train.steps)
    return out


def densify_steps(cfg: GenerateConfig) -> dict[str, int | None]:
    """The steps where ``DensifyConfig.due`` holds, as a progression (computed, not
    enumerated: a billion steps print at once)."""
    d = cfg.density.densify
    return progression(d.start + 1, min(d.until, cfg.train.steps) - 1, d.every, 0)


def cull_steps(cfg: GenerateConfig) -> dict[str, int | None]:
    """The steps where ``CullConfig.due`` holds, as a progression."""
    c = cfg.density.cull
    return progression(c.after + 1, cfg.train.steps - 1, c.every, -c.offset)


def progression(low: int, high: int, every: int, residue: int) -> dict[str, int | None]:
    """The steps s in [max(low, 0), high] with s = residue (mod every): first, last,
    every and count (first and last None when there is none)."""
    low = max(low, 0)
    first = low + (residue - low) % every
    last = high - (high - residue) % every
    if first > last:
        return {"first": None, "last": None, "every": every, "count": 0}
    return {"first": first, "last": last, "every": every, "count": (last - first) // every + 1}


def steps_of(steps: dict[str, int | None]) -> list[int]:
    """The steps of a ``progression``, listed (for a short one)."""
    if not steps["count"]:
        return []
    assert steps["first"] is not None and steps["last"] is not None and steps["every"]
    return list(range(steps["first"], steps["last"] + 1, steps["every"]))


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
