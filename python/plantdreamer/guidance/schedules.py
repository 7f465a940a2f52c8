"""Timestep schedules for SDS: which noise levels are sampled at which optimisation step.

A schedule is a piecewise-constant table of stages ``(until_step, min_frac, max_frac)``: for
``step < until_step`` (the first stage that matches), the diffusion timestep is drawn
uniformly from the integers ``[int(N * min_frac), int(N * max_frac)]`` inclusive, where N is the
scheduler's ``num_train_timesteps`` (1000 for Stable Diffusion). This integer rounding is
threestudio's (``int(num_train_timesteps * percent)``), which the released code uses. The last
stage has ``until_step=None`` and covers every later step.

Built-in tables (both defined for a 3600-step run):

- ``paper``: the PlantDreamer paper's four stages, 0.2-0.98 below step 600, 0.12-0.35 until
  1000, 0.12-0.25 until 2000, then 0.075-0.15.
- ``released``: the authors' released code, U[0.02, 0.98] up to step 500, then [0.02, 0.55].
  Their yaml's ramp ``[500, 0.98, 0.50, 501]`` would give 0.50 from step 501, but their
  system (``system/gaussian_splatting.py:59-61``) sets 0.02-0.55 whenever the step is past
  500, later in each step than the ramp, so 0.55 is what runs.

A run of a different length scales the built-in stage boundaries proportionally
(``TimestepSchedule.scaled``), so a short test run still passes through every stage.
User tables (``parse_schedule``) are used as written.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from plantdreamer.errors import InputError

# Number of optimisation steps the built-in tables were written for (paper and released code).
REFERENCE_STEPS = 3600


@dataclass(frozen=True)
class Stage:
    """Timesteps in [min_frac, max_frac] of the diffusion range while ``step < until_step``."""

    until_step: int | None
    min_frac: float
    max_frac: float


class TimestepSchedule:
    """A piecewise-constant table of timestep ranges over the optimisation steps."""

    def __init__(self, stages: Sequence[Stage | tuple[int | None, float, float]]):
        parsed = [s if isinstance(s, Stage) else Stage(*s) for s in stages]
        if not parsed:
            raise InputError("a timestep schedule needs at least one stage")
        previous = 0
        for i, stage in enumerate(parsed):
            last = i == len(parsed) - 1
            if not 0.0 <= stage.min_frac <= stage.max_frac <= 1.0:
                raise InputError(
                    f"stage {i}: need 0 <= min <= max <= 1, got {stage.min_frac}-{stage.max_frac}"
                )
            if last != (stage.until_step is None):
                raise InputError("only the last stage is open-ended (until_step=None)")
            if stage.until_step is not None:
                if stage.until_step <= previous:
                    raise InputError(
                        f"stage boundaries must increase, got {stage.until_step} after {previous}"
                    )
                previous = stage.until_step
        self.stages: tuple[Stage, ...] = tuple(parsed)

    def __repr__(self) -> str:
        return f"TimestepSchedule({list(self.stages)!r})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, TimestepSchedule) and self.stages == other.stages

    def fractions(self, step: int) -> tuple[float, float]:
        """The (min, max) fraction of the diffusion range used at ``step``."""
        if step < 0:
            raise InputError(f"step must be >= 0, got {step}")
        for stage in self.stages:
            if stage.until_step is None or step < stage.until_step:
                return stage.min_frac, stage.max_frac
        raise AssertionError("unreachable: the last stage is open-ended")

    def bounds(self, step: int, num_train_timesteps: int = 1000) -> tuple[int, int]:
        """Inclusive integer timestep range at ``step``, clamped to valid timesteps."""
        lo, hi = self.fractions(step)
        top = num_train_timesteps - 1
        return min(int(num_train_timesteps * lo), top), min(int(num_train_timesteps * hi), top)

    def sample_timestep(
        self,
        step: int,
        rng: torch.Generator,
        batch_size: int = 1,
        num_train_timesteps: int = 1000,
    ) -> torch.Tensor:
        """``batch_size`` timesteps (int64, on ``rng``'s device) drawn uniformly from
        ``bounds(step)``."""
        lo, hi = self.bounds(step, num_train_timesteps)
        return torch.randint(
            lo, hi + 1, (batch_size,), generator=rng, dtype=torch.long, device=rng.device
        )

    def scaled(self, total_steps: int, reference_steps: int = REFERENCE_STEPS) -> TimestepSchedule:
        """The same table with its boundaries stretched from ``reference_steps`` to ``total_steps``."""
        if total_steps <= 0:
            raise InputError(f"total_steps must be positive, got {total_steps}")
        if total_steps == reference_steps:
            return self
        stages: list[Stage] = []
        previous = 0
        for stage in self.stages:
            until = stage.until_step
            if until is not None:
                # Keep boundaries strictly increasing even for very short runs.
                until = max(previous + 1, round(until * total_steps / reference_steps))
                previous = until
            stages.append(Stage(until, stage.min_frac, stage.max_frac))
        return TimestepSchedule(stages)


def paper_schedule() -> TimestepSchedule:
    """The paper's four stages (Section 4, implementation details)."""
    return TimestepSchedule(
        [(600, 0.2, 0.98), (1000, 0.12, 0.35), (2000, 0.12, 0.25), (None, 0.075, 0.15)]
    )


def released_code_schedule() -> TimestepSchedule:
    """The authors' released code: 0.02-0.98, then 0.02-0.55 from step 501."""
    return TimestepSchedule([(501, 0.02, 0.98), (None, 0.02, 0.55)])


BUILTIN_SCHEDULES = {"paper": paper_schedule, "released": released_code_schedule}


def parse_schedule(text: str) -> TimestepSchedule:
    """A user table written as ``"0.2-0.98@600,0.12-0.35@1000,0.075-0.15"``.

    Each comma-separated stage is ``min-max@until_step``; the last one has no ``@``.
    """
    stages: list[tuple[int | None, float, float]] = []
    for i, part in enumerate(p.strip() for p in text.split(",")):
        try:
            span, _, until = part.partition("@")
            lo, hi = (float(x) for x in span.split("-"))
            stages.append((int(until) if until else None, lo, hi))
        except ValueError as exc:
            raise InputError(
                f"cannot read timestep stage {i} {part!r}: expected 'min-max@until_step' "
                f"(last stage 'min-max'), e.g. '0.2-0.98@600,0.075-0.15'"
            ) from exc
    return TimestepSchedule(stages)


def make_schedule(
    spec: str | TimestepSchedule | Sequence[tuple[int | None, float, float]],
    total_steps: int = REFERENCE_STEPS,
) -> TimestepSchedule:
    """A schedule from a built-in name (scaled to ``total_steps``), a table string, or stages."""
    if isinstance(spec, TimestepSchedule):
        return spec
    if isinstance(spec, str):
        if spec in BUILTIN_SCHEDULES:
            return BUILTIN_SCHEDULES[spec]().scaled(total_steps)
        if "-" in spec:
            return parse_schedule(spec)
        raise InputError(
            f"unknown timestep schedule {spec!r}: use one of {sorted(BUILTIN_SCHEDULES)} "
            "or a table like '0.2-0.98@600,0.075-0.15'"
        )
    return TimestepSchedule(spec)


def ramp(step: int, start_step: int, start_value: float, end_value: float, end_step: int) -> float:
    """Linear ramp from ``start_value`` at ``start_step`` to ``end_value`` at ``end_step``.

    threestudio's ``C([start_step, start_value, end_value, end_step], ...)``; the gradient
    clamp of the released code is ``ramp(step, 0, 1.5, 2.0, 1000)``.
    """
    if end_step <= start_step:
        return end_value if step >= end_step else start_value
    frac = min(max((step - start_step) / (end_step - start_step), 0.0), 1.0)
    return start_value + (end_value - start_value) * frac
