"""Did a run draw its diffusion timesteps as its schedule says? Read from its ``log.csv``.

The guidance draws each sample's t uniformly from the step's inclusive integer range
[lo, hi] (``TimestepSchedule.sample_timestep``) and logs every draw (the per-sample column
``TIMESTEPS_STAT``; a plant in a group logs its own) beside the bounds. Two checks:

- **Bounds**: every draw inside its step's logged bounds, and those bounds the schedule
  table's at the run's length.
- **Distribution**: a draw m = t - lo of a range of n = hi - lo + 1 integers falls in bin
  ``(2m + 1) * K // (2n)`` of K equal bins of u = (m + 0.5) / n, the middle of its cell in
  (0, 1); each bin's expected count is summed over the draws from the exact share of the
  n integers that fall in it (so ranges of any width count, unequal shares included).
  Pearson's chi-square over the bins expected to hold anything (degrees of freedom: one
  fewer than those bins) gives ``timesteps_uniform_p``. K = 10, fewer for short runs so that each bin expects at
  least 5 draws (Cochran's rule); a range of one integer (lo = hi) says nothing and is
  left out. A right run fails with probability about ``MIN_UNIFORM_P``: measured over
  simulated runs of the real sampler by ``scripts/timestep_false_alarms.py``
  (docs/known_answer.md).
"""

from __future__ import annotations

import csv
import functools
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from plantdreamer.guidance.base import TIMESTEPS_STAT
from plantdreamer.guidance.schedules import make_schedule
from plantdreamer.pipeline.outputs import read_samples_cell

# The p threshold: a right 200-step run fails about once in 10,000 (docs/known_answer.md).
MIN_UNIFORM_P = 1e-4
MAX_BINS = 10
MIN_EXPECTED_PER_BIN = 5


@functools.lru_cache(maxsize=4096)
def bin_shares(n: int, bins: int) -> np.ndarray:
    """The share of a range of ``n`` integers that falls in each of ``bins`` bins of u."""
    m = np.arange(n, dtype=np.int64)
    return np.bincount((2 * m + 1) * bins // (2 * n), minlength=bins) / n


def uniform_p(t: Sequence[int], lo: Sequence[int], hi: Sequence[int]) -> float | None:
    """Pearson's chi-square p that the draws ``t`` (each inside its inclusive range
    [``lo``, ``hi``]) are uniform over their ranges (module docstring); None when they say
    nothing (too few draws from ranges of more than one integer)."""
    t_, lo_, hi_ = (np.asarray(a, dtype=np.int64) for a in (t, lo, hi))
    useful = hi_ > lo_
    m, n = (t_ - lo_)[useful], (hi_ - lo_ + 1)[useful]
    bins = min(MAX_BINS, len(m) // MIN_EXPECTED_PER_BIN)
    if bins < 2:
        return None
    observed = np.bincount((2 * m + 1) * bins // (2 * n), minlength=bins)
    widths, counts = np.unique(n, return_counts=True)
    expected = sum(c * bin_shares(int(w), bins) for w, c in zip(widths, counts, strict=True))
    kept = expected > 0
    chi2 = float((((observed - expected) ** 2)[kept] / expected[kept]).sum())
    # The chi-square survival function: the regularised upper incomplete gamma function.
    dof, half = torch.tensor(int(kept.sum()) - 1, dtype=torch.float64) / 2, chi2 / 2
    return float(torch.special.gammaincc(dof, torch.tensor(half, dtype=torch.float64)))


def run_timesteps(
    logs: Path | Sequence[Path], steps: int, schedule_name: str = "paper"
) -> dict[str, Any]:
    """Did a run's timesteps follow its schedule? From what the run wrote (its ``log.csv``,
    or every plant's of a group: the draws of each sample, their batch mean, and the bounds
    they were drawn within): the draws outside their logged bounds, the steps whose bounds
    differ from ``schedule_name``'s table at a ``steps``-long run, and the draws' uniformity
    within their bounds (module docstring)."""
    table = make_schedule(schedule_name, max(steps, 1))
    paths = [logs] if isinstance(logs, Path) else list(logs)
    rows: list[dict[str, str]] = []
    complete = bool(paths)
    for path in paths:
        with path.open(newline="") as f:
            these = list(csv.DictReader(f))
        complete &= len(these) == steps
        rows += these
    outside = wrong_bounds = unlogged = mean_outside = 0
    inside: list[tuple[int, int, int]] = []  # (t, lo, hi)
    for row in rows:
        lo, hi = int(float(row["t_min"])), int(float(row["t_max"]))
        wrong_bounds += (lo, hi) != table.bounds(int(row["step"]))
        mean_outside += not lo <= float(row["timestep"]) <= hi
        samples = read_samples_cell(row.get(TIMESTEPS_STAT) or "")
        unlogged += not samples
        for t in samples:
            if lo <= t <= hi and t == int(t):
                inside.append((int(t), lo, hi))
            else:
                outside += 1
    p = uniform_p(*zip(*inside, strict=True)) if inside else None
    return {
        "timestep_steps": len(rows),
        "timestep_samples": len(inside) + outside,
        "timesteps_outside_bounds": outside,
        "timestep_means_outside_bounds": mean_outside,
        "timestep_bounds_not_in_table": wrong_bounds,
        "timestep_steps_without_samples": unlogged,
        "timesteps_uniform_p": p,
        "timesteps_follow_schedule": bool(rows)
        and complete
        and outside + wrong_bounds + unlogged == 0
        and (p is None or p >= MIN_UNIFORM_P),
    }
