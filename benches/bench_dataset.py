"""Throughput of `plantdreamer dataset` on a local Ray instance, and what Ray costs.

12 L-System plants (bean, mint, kale x 4 seeds) with `--guidance none`, 20k points,
20 steps, 4 evaluation views at 128 px. Three runs, each a fresh process:
- one process calling `generate` 12 times in a row, on 1 thread (the baseline: no Ray);
- `plantdreamer dataset --local-cpus 1`: Ray with one worker (1 CPU per plant);
- `plantdreamer dataset --local-cpus 2`: two workers.
Wall times include everything a user waits for (Ray start and stop, worker start-up,
torch imports). Ray's overhead is the one-worker wall time minus the baseline's.

    python benches/bench_dataset.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
SPECIES = ("bean", "mint", "kale")
SEEDS = range(4)
SETTINGS = {"guidance": "none", "n_points": 20_000, "steps": 20, "eval_views": 4, "resolution": 128}
FLAGS = ["--guidance", "none", "--points", "20000", "--steps", "20", "--eval-views", "4",
         "--resolution", "128"]  # fmt: skip
BASELINE = """
import sys, time
from plantdreamer.pipeline import GenerateConfig, generate
settings, out = {settings!r}, sys.argv[1]
t0 = time.perf_counter()
for species in {species!r}:
    for seed in {seeds!r}:
        cfg = GenerateConfig(species=species, seed=seed, **settings)
        generate(cfg, f"{{out}}/{{species}}-{{seed}}", show_progress=False)
print(time.perf_counter() - t0)
"""


def one_thread_env() -> dict[str, str]:
    return {**os.environ, "RAYON_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


def baseline(tmp: Path) -> tuple[float, float]:
    """Wall time of the whole process, and of the 12 generate calls inside it."""
    code = BASELINE.format(settings=SETTINGS, species=SPECIES, seeds=list(SEEDS))
    t0 = time.perf_counter()
    out = subprocess.run(
        [sys.executable, "-c", code, str(tmp / "baseline")],
        env=one_thread_env(),
        check=True,
        capture_output=True,
        text=True,
    )
    return time.perf_counter() - t0, float(out.stdout.strip().splitlines()[-1])


def dataset(tmp: Path, cpus: int) -> tuple[float, float]:
    """Wall time of the command, and the mean time of one plant inside its worker."""
    out = tmp / f"ray{cpus}"
    cmd = [sys.executable, "-m", "plantdreamer.cli", "dataset", "--species", ",".join(SPECIES),
           "--count", str(len(SEEDS)), "--local-cpus", str(cpus), *FLAGS, "--quiet",
           "--out", str(out)]  # fmt: skip
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    wall = time.perf_counter() - t0
    records = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    assert len(records) == 12 and all(r["status"] == "done" for r in records)
    return wall, sum(r["seconds"] for r in records) / len(records)


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        base_wall, base_inner = baseline(tmp)
        runs = {cpus: dataset(tmp, cpus) for cpus in (1, 2)}
    n = len(SPECIES) * len(SEEDS)
    lines = [
        "## Datasets on Ray (`benches/bench_dataset.py`)\n",
        "Command: `python benches/run_all.py dataset`. 12 L-System plants (bean, mint, kale x",
        "4 seeds), `--guidance none`, 20k points, 20 steps, 4 evaluation views at 128 px, on",
        "a local Ray instance. Wall times are of the whole command (Ray start and stop, worker",
        "start-up and imports included), one run each. Measured on the shared 2-core machine",
        "while other work ran on it: the figures move by tens of percent between runs.\n",
        "| run | wall (s) | plants/minute | mean time of one plant inside its process (s) |",
        "|---|---|---|---|",
        f"| 12 x `generate` in one process, 1 thread (no Ray) | {base_wall:.1f} "
        f"| {n / base_wall * 60:.1f} | {base_inner / n:.2f} |",
    ]
    for cpus, (wall, per_plant) in runs.items():
        lines.append(
            f"| `dataset`, {cpus} worker{'s' if cpus > 1 else ''} (1 CPU each) | {wall:.1f} "
            f"| {n / wall * 60:.1f} | {per_plant:.2f} |"
        )
    overhead = runs[1][0] - base_wall
    lines += [
        "",
        f"Ray's overhead with one worker: {overhead:.1f} s for the 12 plants "
        f"({overhead / n:.2f} s per plant) over the single process; with two workers the",
        f"dataset ran {base_wall / runs[2][0]:.2f}x as fast as the single process.",
        "",
    ]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "dataset.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
