"""``python scripts/gpu_checks.py dataset OUT``: `plantdreamer dataset --plants-per-gpu B` on
CUDA with the full-size networks (random weights saved in the hub's layout, loaded by the
real loading code, as ``resume`` does); ``--tiny`` runs the same on the CPU.

For each B of ``--groups`` (default 1 and 4), a dataset of ``--plants`` L-System beans
(default 8, seeds 0..7) trains ``--steps`` steps (default 40) on a local Ray instance with
every GPU of the machine. The report gives each run's exit status and wall time (Ray
start, model loading and exports included), every plant's status, the worker processes
that ran them (one per GPU: the models loaded once each), and plants per hour per GPU,
projected to 3600-step plants from the training phases the manifest records (each plant
its share of its group's; units one after another on the GPU). With SDS a plant made in a
group is not the plant made alone, so the runs are compared by their statuses only.
Writes ``OUT/dataset.json``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

STEPS_PER_PLANT = 3600


def _models(args: argparse.Namespace) -> tuple[Path, Path]:
    from plantdreamer.guidance.full_size import save_full_size_models
    from plantdreamer.guidance.tiny import save_tiny_models

    base, control = args.models / "base", args.models / "controlnet"
    if not (base / "model_index.json").exists() or not (control / "config.json").exists():
        if args.tiny:
            save_tiny_models(args.models)
        else:
            save_full_size_models(args.models, seed=0, device=args.device)
    return base, control


def _one_run(args: argparse.Namespace, b: int, base: Path, control: Path, out: Path) -> dict:
    work = args.work / f"dataset-b{b}"
    shutil.rmtree(work, ignore_errors=True)
    cmd = [
        sys.executable, "-m", "plantdreamer", "dataset", "--species", args.species,
        "--seeds", f"0-{args.plants - 1}", "--plants-per-gpu", str(b), "--steps", str(args.steps),
        "--points", str(args.points), "--resolution", str(args.resolution),
        "--eval-views", "2", "--quiet", "--set", f"base-model={json.dumps(str(base))}",
        "--set", f"controlnet={json.dumps(str(control))}", "--set",
        f"device={json.dumps(args.device)}", "--set", f"sds-resolution={args.sds_resolution}",
        "--set", "turntable=\"none\"", "--out", str(work),
    ]  # fmt: skip
    if args.tiny:
        cmd += ["--gpus-per-plant", "0", "--cpus-per-plant", "1"]  # a CPU dry run
    t0 = time.perf_counter()
    with (out / f"dataset-b{b}.log").open("w") as log:
        rc = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - t0
    records = [json.loads(line) for line in (work / "manifest.jsonl").read_text().splitlines()]
    from plantdreamer.pipeline.export import STEP_PHASES

    done_records = [r for r in records if r["status"] == "done"]
    units = {tuple(r.get("trained_with", [r["id"]])) for r in done_records}
    # Each plant records its share of its group's phases: the sum is the GPU's time.
    phases = sum(r["timings_s"].get(p, 0.0) for r in done_records for p in STEP_PHASES)
    train_s = phases * STEPS_PER_PLANT / args.steps
    done = len(done_records)
    return {
        "B": b,
        "rc": rc,
        "wall_s": round(wall, 1),
        "statuses": {r["id"]: r["status"] for r in records},
        "units": len(units),
        "plants_per_hour_3600_steps": round(3600 * done / train_s, 2) if train_s else None,
        "pids": sorted({r.get("pid") for r in records}),
    }


def run_dataset_check(args: argparse.Namespace, out: Path) -> int:
    base, control = _models(args)
    runs: list[dict[str, Any]] = [_one_run(args, b, base, control, out) for b in args.groups]
    report = {"steps": args.steps, "plants": args.plants, "device": args.device, "runs": runs}
    (out / "dataset.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))
    ok = all(r["rc"] == 0 and set(r["statuses"].values()) == {"done"} for r in runs)
    return 0 if ok else 1
