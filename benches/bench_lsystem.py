"""Benchmark: grow one L-System plant and sample 100k points from it, per species.

    .venv/bin/python benches/bench_lsystem.py [--reps 7]

Writes benches/results/lsystem.md (and lsystem.json beside it). The target is under 1 s per
plant including the 100k-point sampling.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

from plantdreamer.lsystem import generate_plant, list_species, sample_points

RESULTS = Path(__file__).resolve().parent / "results"
SEEDS = (0, 1, 2)
POINTS = 100_000


def best_of(fn, reps: int) -> float:
    times = []
    for _ in range(reps):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=7)
    args = parser.parse_args()
    rows = []
    for name in list_species():
        for seed in SEEDS:
            mesh = generate_plant(name, seed)  # warm-up, and the sizes for the table
            grow_s = best_of(lambda name=name, seed=seed: generate_plant(name, seed), args.reps)
            sample_s = best_of(
                lambda mesh=mesh, seed=seed: sample_points(mesh, POINTS, seed), args.reps
            )
            total_s = best_of(
                lambda name=name, seed=seed: sample_points(
                    generate_plant(name, seed), POINTS, seed
                ),
                args.reps,
            )
            rows.append(
                {
                    "species": name,
                    "seed": seed,
                    "vertices": len(mesh.vertices),
                    "faces": len(mesh.faces),
                    "leaves": mesh.n_leaves,
                    "grow_s": grow_s,
                    "sample_s": sample_s,
                    "total_s": total_s,
                }
            )
            print(f"{name} seed {seed}: {total_s * 1000:.0f} ms", flush=True)

    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "lsystem.json").write_text(json.dumps(rows, indent=2))
    table = [
        "| species | seed | vertices | faces | leaves | grow (ms) | sample 100k (ms) | total (ms) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        table.append(
            f"| {r['species']} | {r['seed']} | {r['vertices']} | {r['faces']} | {r['leaves']} "
            f"| {r['grow_s'] * 1e3:.0f} | {r['sample_s'] * 1e3:.0f} | {r['total_s'] * 1e3:.0f} |"
        )
    worst = max(r["total_s"] for r in rows)
    text = (
        "## L-System plants (`plantdreamer.lsystem`)\n\n"
        "Command: `.venv/bin/python benches/bench_lsystem.py` "
        f"(minimum of {args.reps} repetitions each; Python {platform.python_version()}, "
        "pure numpy, single thread).\n\n"
        "*grow* is `generate_plant(species, seed)`: derive the L-System string, run the turtle, "
        "build stems, leaves, pot and soil. *sample* is `sample_points(mesh, 100_000)`. "
        "*total* is both, the issue's target being under 1 s.\n\n"
        + "\n".join(table)
        + f"\n\nSlowest total: {worst * 1e3:.0f} ms "
        f"({'meets' if worst < 1.0 else 'misses'} the < 1 s target). Measured on a shared, "
        "loaded 2-core machine where other builds were running: minima are the least "
        "disturbed runs, not typical ones.\n"
    )
    (RESULTS / "lsystem.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
