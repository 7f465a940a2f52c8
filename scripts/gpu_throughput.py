"""``python scripts/gpu_checks.py throughput OUT``: plants per hour with several plants in
one trainer, and Ctrl-C + resume of a group, with the full-size networks (random weights
built in-process, SD 2.1-base sizes) on CUDA; ``--tiny`` runs the same on the CPU.

For each B (default 1, 4, 8) one group of B L-System beans (seeds 0..B-1) trains for
``--steps`` steps; the report gives the group's per-phase step times (ms), plants per hour
projected to 3600-step plants, the wall time and the peak CUDA memory. Then a group of 4 is
run straight through, and again stopped by SIGINT after step ``--steps // 2`` and resumed;
every plant's plant.ply and masks must be byte-identical. Writes ``OUT/throughput.json``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import signal
import time
from pathlib import Path
from typing import Any

PHASES = ("render", "depth", "guidance", "backward", "optimizer")


def _configs(args: argparse.Namespace, b: int) -> list[Any]:
    from plantdreamer.pipeline import GenerateConfig

    return [
        GenerateConfig.of(
            species="bean", seed=s, steps=args.steps, points=args.points,
            resolution=args.resolution, sds_resolution=args.sds_resolution, eval_views=2,
            turntable_frames=2, turntable="none", checkpoint_every=max(1, args.steps // 4),
            device=args.device,
        )
        for s in range(b)
    ]  # fmt: skip


def _hashes(folder: Path) -> dict[str, str]:
    names = ["plant.ply", *[str(p.relative_to(folder)) for p in sorted(folder.glob("*/*.png"))]]
    return {n: hashlib.sha256((folder / n).read_bytes()).hexdigest() for n in names}


def run_throughput(args: argparse.Namespace, out: Path) -> int:
    import torch

    from plantdreamer.guidance import StableDiffusionDepthGuidance
    from plantdreamer.pipeline import RunInterrupted
    from plantdreamer.pipeline.group import generate_group

    if args.tiny:
        from plantdreamer.guidance.tiny import tiny_models

        parts, args.device = tiny_models(), "cpu"
    else:
        from plantdreamer.guidance.full_size import full_size_models

        parts = full_size_models(device=args.device)
    cuda = args.device.startswith("cuda")

    def guidance() -> Any:
        return StableDiffusionDepthGuidance(
            species="bean", components=parts, resolution=args.sds_resolution,
            device=args.device, seed=0,
        )  # fmt: skip

    work = args.work / "throughput"
    report: dict[str, Any] = {"device": args.device, "steps": args.steps, "groups": {}}
    for b in args.groups:
        if cuda:
            torch.cuda.reset_peak_memory_stats()
        t0 = time.perf_counter()
        result = generate_group(_configs(args, b), work / f"b{b}", guidance=guidance(),
                                overwrite=True, show_progress=False)  # fmt: skip
        wall = time.perf_counter() - t0
        timings = json.loads((work / f"b{b}" / "bean-s0000" / "run.json").read_text())
        per_step = {k: 1000 * timings["timings_s"].get(k, 0.0) / args.steps for k in PHASES}
        step_s = sum(per_step.values()) / 1000
        report["groups"][b] = {
            "failed": result.failed,
            "step_ms": per_step,
            "plants_per_hour": 3600 * b / (step_s * 3600),
            "wall_s": wall,
            "peak_cuda_gib": torch.cuda.max_memory_allocated() / 2**30 if cuda else None,
        }
        print(b, json.dumps(report["groups"][b]), flush=True)
    # Ctrl-C and --resume of a group of 4: byte-identical to the straight run.
    cfgs = _configs(args, 4)
    generate_group(cfgs, work / "straight", guidance=guidance(), overwrite=True,
                   show_progress=False)  # fmt: skip

    def ctrl_c(step: int) -> None:
        if step == args.steps // 2:
            os.kill(os.getpid(), signal.SIGINT)

    stopped = None
    try:
        generate_group(cfgs, work / "cut", guidance=guidance(), overwrite=True,
                       show_progress=False, on_step=ctrl_c)  # fmt: skip
    except RunInterrupted as stop:
        stopped = stop.step
    generate_group(None, work / "cut", guidance=guidance(), resume=True, show_progress=False)
    names = [f"bean-s{s:04d}" for s in range(4)]
    same = {n: _hashes(work / "straight" / n) == _hashes(work / "cut" / n) for n in names}
    report["resume"] = {"stopped_at": stopped, "identical": same}
    (out / "throughput.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))
    return 0 if stopped is not None and all(same.values()) else 1
