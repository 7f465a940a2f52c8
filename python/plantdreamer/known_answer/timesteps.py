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
- **Independence**: draws that are uniform one by one can still depend on each other (one
  t shared by a group's plants, a draw repeated at the next step). Each draw is
  standardised, z = (u - 1/2) / sd with u's exact mean 1/2 and variance (n^2 - 1) / (12 n^2),
  and multiplied with its neighbours: the next draw in the same log, and the draw at the
  same step and sample of the next plant's log. Under independence each product has mean 0
  and variance 1 and no two are correlated, so each kind's sum over the square root of its
  count is about a standard normal; ``timesteps_independent_p`` is the smaller two-sided p
  of the two kinds, doubled, failed under the same ``MIN_UNIFORM_P`` (its calibration
  measured by the same script).
"""

from __future__ import annotations

import csv
import functools
import itertools
import math
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
# Fewer neighbour pairs than this say too little for the normal approximation.
MIN_PAIRS = 10


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


def standardised(t: int, lo: int, hi: int) -> float | None:
    """A draw t of the inclusive range [lo, hi] as z: mean 0 and variance 1 when t is
    uniform there; None for a range of one integer (it says nothing)."""
    n = hi - lo + 1
    if n < 2:
        return None
    u = (t - lo + 0.5) / n
    return (u - 0.5) / math.sqrt((n * n - 1) / (12.0 * n * n))


def _normal_p(products: list[float]) -> float | None:
    """Two-sided p of the sum of uncorrelated mean-0, variance-1 products."""
    if len(products) < MIN_PAIRS:
        return None
    return math.erfc(abs(sum(products)) / math.sqrt(len(products)) / math.sqrt(2.0))


def independent_p(logs: Sequence[Sequence[Sequence[float | None]]]) -> float | None:
    """Two-sided p that standardised draws are independent (module docstring).

    ``logs[k][step]`` holds plant k's standardised draws at that step (None for one that
    says nothing). Two sums of products: each draw with the next one in its log (step by
    step, sample by sample), and each with the same step and sample of the next log; the
    smaller p, doubled (Bonferroni), so that neither kind of pair dilutes the other. None
    when neither has ``MIN_PAIRS`` pairs."""
    serial: list[float] = []
    across: list[float] = []
    for k, log in enumerate(logs):
        flat = [z for step in log for z in step]
        serial += [a * b for a, b in itertools.pairwise(flat) if a is not None and b is not None]
        if k + 1 < len(logs):
            for here, there in zip(log, logs[k + 1], strict=False):
                across += [
                    a * b
                    for a, b in zip(here, there, strict=False)
                    if a is not None and b is not None
                ]
    ps = [p for p in (_normal_p(serial), _normal_p(across)) if p is not None]
    return min(1.0, len(ps) * min(ps)) if ps else None


def run_timesteps(
    logs: Path | Sequence[Path], steps: int, schedule_name: str = "paper"
) -> dict[str, Any]:
    """Did a run's timesteps follow its schedule? From what the run wrote (its ``log.csv``,
    or every plant's of a group: the draws of each sample, their batch mean, and the bounds
    they were drawn within): the draws outside their logged bounds, the steps whose bounds
    differ from ``schedule_name``'s table at a ``steps``-long run, and the draws' uniformity
    within their bounds and their independence (module docstring)."""
    table = make_schedule(schedule_name, max(steps, 1))
    paths = [logs] if isinstance(logs, Path) else list(logs)
    rows: list[dict[str, str]] = []
    complete = bool(paths)
    z_logs: list[list[list[float | None]]] = []  # per log, per step: standardised draws
    outside = wrong_bounds = unlogged = mean_outside = 0
    inside: list[tuple[int, int, int]] = []  # (t, lo, hi)
    for path in paths:
        with path.open(newline="") as f:
            these = list(csv.DictReader(f))
        complete &= len(these) == steps
        rows += these
        z_logs.append([])
        for row in these:
            lo, hi = int(float(row["t_min"])), int(float(row["t_max"]))
            wrong_bounds += (lo, hi) != table.bounds(int(row["step"]))
            mean_outside += not lo <= float(row["timestep"]) <= hi
            samples = read_samples_cell(row.get(TIMESTEPS_STAT) or "")
            unlogged += not samples
            z_logs[-1].append([])
            for t in samples:
                if lo <= t <= hi and t == int(t):
                    inside.append((int(t), lo, hi))
                    z_logs[-1][-1].append(standardised(int(t), lo, hi))
                else:
                    outside += 1
                    z_logs[-1][-1].append(None)
    p = uniform_p(*zip(*inside, strict=True)) if inside else None
    p_independent = independent_p(z_logs)
    return {
        "timestep_steps": len(rows),
        "timestep_samples": len(inside) + outside,
        "timesteps_outside_bounds": outside,
        "timestep_means_outside_bounds": mean_outside,
        "timestep_bounds_not_in_table": wrong_bounds,
        "timestep_steps_without_samples": unlogged,
        "timesteps_uniform_p": p,
        "timesteps_independent_p": p_independent,
        "timesteps_follow_schedule": bool(rows)
        and complete
        and outside + wrong_bounds + unlogged == 0
        and (p is None or p >= MIN_UNIFORM_P)
        and (p_independent is None or p_independent >= MIN_UNIFORM_P),
    }
