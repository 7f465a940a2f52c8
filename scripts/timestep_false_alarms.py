"""Measures the timestep check's false alarms and its power over simulated runs.

    python scripts/timestep_false_alarms.py --runs 100000 --broken-runs 2000 --steps 10,50,100,200

A simulated run draws one timestep per step from the real sampler
(``TimestepSchedule.sample_timestep`` of the paper table at that run length, as the guidance
draws it; the runs are the columns of one batch of draws per step, from one seeded
generator) and is judged by the check's own ``uniform_p`` and ``independent_p`` against
``MIN_UNIFORM_P``. For each run length it prints the right runs that fail either test (and
each test's own failures below 1e-4, 1e-3 and 1e-2, to show the p-values are calibrated;
the independence test also over right groups of two plants, two columns), then the share
of broken runs caught: each right draw mapped to u = (t - lo) / (hi - lo) and skewed to
u**2 or to the lower half of the range; each odd step's draw the previous step's u again;
and a group of two whose second plant is given the first one's t
(docs/known_answer.md, "What the check catches").
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import torch

from plantdreamer.guidance.schedules import make_schedule
from plantdreamer.known_answer.timesteps import (
    MIN_UNIFORM_P,
    independent_p,
    standardised,
    uniform_p,
)

Bounds = list[tuple[int, int]]


def squared(t: torch.Tensor, lo: int, hi: int) -> torch.Tensor:
    """The draws skewed to u**2: most of them near the range's low end."""
    u = (t - lo).double() / max(hi - lo, 1)
    return lo + torch.round((hi - lo) * u**2).long()


def lower_half(t: torch.Tensor, lo: int, hi: int) -> torch.Tensor:
    """The draws folded into the lower half of the range."""
    return lo + (t - lo) // 2


def skewed(brk: Callable[[torch.Tensor, int, int], torch.Tensor]):  # type: ignore[no-untyped-def]
    """A skew of each step's draws as a break of whole runs ([steps, runs] -> groups)."""

    def broken(t: torch.Tensor, bounds: Bounds) -> list[list[list[int]]]:
        skew = torch.stack([brk(t[s], *bounds[s]) for s in range(len(bounds))])
        return [[run] for run in skew.T.tolist()]

    return broken


def repeated(t: torch.Tensor, bounds: Bounds) -> list[list[list[int]]]:
    """Each odd step's draw the previous step's u again, in this step's range: every draw
    still uniform, but pairs of steps equal."""
    t = t.clone()
    for s in range(1, len(bounds), 2):
        (lo0, hi0), (lo, hi) = bounds[s - 1], bounds[s]
        u = (t[s - 1] - lo0).double() / max(hi0 - lo0, 1)
        t[s] = lo + torch.round((hi - lo) * u).long()
    return [[run] for run in t.T.tolist()]


def shared_in_group(t: torch.Tensor, bounds: Bounds) -> list[list[list[int]]]:
    """Groups of two plants, the second given the first one's draws."""
    return [[run, run] for run in t.T.tolist()[::2]]


BREAKS = {
    "u**2": skewed(squared),
    "lower half": skewed(lower_half),
    "repeated at the next step": repeated,
    "one t for a group of 2": shared_in_group,
}


def draws(steps: int, runs: int, seed: int) -> tuple[torch.Tensor, list[tuple[int, int]]]:
    """[steps, runs] timesteps from the real sampler, and each step's bounds."""
    schedule = make_schedule("paper", steps)
    rng = torch.Generator().manual_seed(seed)
    t = torch.stack([schedule.sample_timestep(s, rng, batch_size=runs) for s in range(steps)])
    return t, [schedule.bounds(s) for s in range(steps)]


def p_values(group: list[list[int]], bounds: Bounds) -> tuple[float, float]:
    """(uniform p, independent p) of one run: its plants' draws, one per step each."""
    lo = [b[0] for b in bounds]
    hi = [b[1] for b in bounds]
    p_uniform = uniform_p([t for run in group for t in run], lo * len(group), hi * len(group))
    z = [[[standardised(t, *b)] for t, b in zip(run, bounds, strict=True)] for run in group]
    p_independent = independent_p(z)
    return (
        1.0 if p_uniform is None else p_uniform,
        1.0 if p_independent is None else p_independent,
    )


def count(ps: list[float], cut: float) -> str:
    n = sum(p < cut for p in ps)
    return f"{n} ({n / len(ps):.2g})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=100_000, help="Right runs per length.")
    ap.add_argument("--broken-runs", type=int, default=2000, help="Broken runs per length.")
    ap.add_argument("--steps", default="10,50,100,200", help="Run lengths.")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    t0 = time.perf_counter()
    cuts = (MIN_UNIFORM_P, 1e-3, 1e-2)
    print(f"threshold p < {MIN_UNIFORM_P:g}; {args.runs} right runs per length")
    print("| steps | right runs failing | uniform p < 1e-4 / 1e-3 / 1e-2 |", end=" ")
    print(
        "independent p < 1e-4 / 1e-3 / 1e-2 | groups of 2: independent p < 1e-4 / 1e-2 |", end=" "
    )
    print(" | ".join(f"{name} caught" for name in BREAKS), "|")
    print("|---" * (5 + len(BREAKS)) + "|")
    for steps in (int(s) for s in args.steps.split(",")):
        t, bounds = draws(steps, args.runs, args.seed + steps)
        right = [p_values([run], bounds) for run in t.T.tolist()]
        columns = t.T.tolist()
        groups = [
            p_values([a, b], bounds) for a, b in zip(columns[::2], columns[1::2], strict=False)
        ]
        row = [str(steps), count([min(p) for p in right], MIN_UNIFORM_P)]
        for which in (0, 1):
            row.append(" / ".join(count([p[which] for p in right], c) for c in cuts))
        row.append(" / ".join(count([p[1] for p in groups], c) for c in (cuts[0], cuts[2])))
        for brk in BREAKS.values():
            broken = brk(t[:, : 2 * args.broken_runs], bounds)[: args.broken_runs]
            caught = sum(min(p_values(g, bounds)) < MIN_UNIFORM_P for g in broken)
            row.append(f"{caught} of {len(broken)}")
        print("| " + " | ".join(row) + " |", flush=True)
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
