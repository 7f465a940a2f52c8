"""Measures the timestep check's false alarms and its power over simulated runs.

    python scripts/timestep_false_alarms.py --runs 100000 --broken-runs 2000 --steps 10,50,100,200

A simulated run draws one timestep per step from the real sampler
(``TimestepSchedule.sample_timestep`` of the paper table at that run length, as the guidance
draws it; the runs are the columns of one batch of draws per step, from one seeded
generator) and is judged by the check's own ``uniform_p`` against ``MIN_UNIFORM_P``. For
each run length it prints the right runs that fail (and those below 1e-3 and 1e-2, to show
the p-values are calibrated), then the share of broken runs caught: each right draw mapped
to u = (t - lo) / (hi - lo) and skewed to u**2 or to the lower half of the range
(docs/known_answer.md, "What the check catches").
"""

from __future__ import annotations

import argparse
import time

import torch

from plantdreamer.guidance.schedules import make_schedule
from plantdreamer.known_answer.timesteps import MIN_UNIFORM_P, uniform_p


def squared(t: torch.Tensor, lo: int, hi: int) -> torch.Tensor:
    """The draws skewed to u**2: most of them near the range's low end."""
    u = (t - lo).double() / max(hi - lo, 1)
    return lo + torch.round((hi - lo) * u**2).long()


def lower_half(t: torch.Tensor, lo: int, hi: int) -> torch.Tensor:
    """The draws folded into the lower half of the range."""
    return lo + (t - lo) // 2


BREAKS = {"u**2": squared, "lower half": lower_half}


def draws(steps: int, runs: int, seed: int) -> tuple[torch.Tensor, list[tuple[int, int]]]:
    """[steps, runs] timesteps from the real sampler, and each step's bounds."""
    schedule = make_schedule("paper", steps)
    rng = torch.Generator().manual_seed(seed)
    t = torch.stack([schedule.sample_timestep(s, rng, batch_size=runs) for s in range(steps)])
    return t, [schedule.bounds(s) for s in range(steps)]


def p_values(t: torch.Tensor, bounds: list[tuple[int, int]]) -> list[float]:
    lo = [b[0] for b in bounds]
    hi = [b[1] for b in bounds]
    out = []
    for run in t.T.tolist():
        p = uniform_p(run, lo, hi)
        out.append(1.0 if p is None else p)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=100_000, help="Right runs per length.")
    ap.add_argument("--broken-runs", type=int, default=2000, help="Broken runs per length.")
    ap.add_argument("--steps", default="10,50,100,200", help="Run lengths.")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    t0 = time.perf_counter()
    print(f"threshold p < {MIN_UNIFORM_P:g}; {args.runs} right runs per length")
    print("| steps | right runs failing | p < 1e-3 | p < 1e-2 |", end=" ")
    print(" | ".join(f"{name} caught" for name in BREAKS), "|")
    print("|---" * (4 + len(BREAKS)) + "|")
    for steps in (int(s) for s in args.steps.split(",")):
        t, bounds = draws(steps, args.runs, args.seed + steps)
        right = p_values(t, bounds)
        row = [str(steps)] + [
            f"{sum(p < cut for p in right)} ({sum(p < cut for p in right) / len(right):.2g})"
            for cut in (MIN_UNIFORM_P, 1e-3, 1e-2)
        ]
        sample = t[:, : args.broken_runs]
        for brk in BREAKS.values():
            broken = torch.stack([brk(sample[s], *bounds[s]) for s in range(steps)])
            caught = sum(p < MIN_UNIFORM_P for p in p_values(broken, bounds))
            row.append(f"{caught} of {sample.shape[1]}")
        print("| " + " | ".join(row) + " |", flush=True)
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
