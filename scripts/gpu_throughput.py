"""``python scripts/gpu_checks.py throughput OUT``: plants per hour with several plants in
one trainer, and Ctrl-C + resume of a group, with the full-size networks (random weights
built in-process, SD 2.1-base sizes) on CUDA; ``--tiny`` runs the same on the CPU.

For each B (default 1, 4, 8) one group of B L-System beans (seeds 0..B-1) trains for
``--steps`` steps as one batch (``overlap off``), and each B of ``--overlap`` (default 4, 8)
also as two halves in flight (``overlap on``), run right after its one-batch twin; the
report gives the group's per-phase step times (ms; "guidance" includes the host's wait for
the device), plants per hour projected to 3600-step plants, the wall time and the peak CUDA
memory, under ``groups`` as ``"B"`` and ``"B-overlap"``. Then a group of 4 with overlap on
is run straight through, and again stopped by SIGINT after step ``--steps // 2`` and
resumed; every plant's plant.ply and masks must be byte-identical. Writes
``OUT/throughput.json``.
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


def _configs(args: argparse.Namespace, b: int, overlap: str = "off") -> list[Any]:
    from plantdreamer.pipeline import GenerateConfig

    return [
        GenerateConfig.of(
            species="bean", seed=s, steps=args.steps, points=args.points,
            resolution=args.resolution, sds_resolution=args.sds_resolution, eval_views=2,
            turntable_frames=2, turntable="none", checkpoint_every=max(1, args.steps // 4),
            device=args.device, overlap=overlap,
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
    runs = [(b, o) for b in args.groups for o in ("off", "on") if o == "off" or b in args.overlap]
    for b, overlap in runs:
        label = str(b) if overlap == "off" else f"{b}-overlap"
        if cuda:
            torch.cuda.reset_peak_memory_stats()
        t0 = time.perf_counter()
        result = generate_group(_configs(args, b, overlap), work / label, guidance=guidance(),
                                overwrite=True, show_progress=False)  # fmt: skip
        wall = time.perf_counter() - t0
        timings = json.loads((work / label / "bean-s0000" / "run.json").read_text())
        per_step = {k: 1000 * timings["timings_s"].get(k, 0.0) / args.steps for k in PHASES}
        step_s = sum(per_step.values()) / 1000
        report["groups"][label] = {
            "failed": result.failed,
            "step_ms": per_step,
            "plants_per_hour": 3600 * b / (step_s * 3600),
            "wall_s": wall,
            "peak_cuda_gib": torch.cuda.max_memory_allocated() / 2**30 if cuda else None,
        }
        print(label, json.dumps(report["groups"][label]), flush=True)
    # Ctrl-C and --resume of a group of 4 in two halves: byte-identical to the straight run.
    cfgs = _configs(args, 4, "on")
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
