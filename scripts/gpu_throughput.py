"""``python scripts/gpu_checks.py throughput OUT``: plants per hour in the steady state with
several plants in one trainer (``benches/bench_throughput.py``: full-size random-weight
networks on CUDA, ``--tiny`` networks on the CPU), then Ctrl-C + resume of a group.

The bench's settings apply (``--groups``, ``--overlap``, ``--vae``, ``--steps``,
``--warmup``, ``--trace``, ...); ``OUT/throughput.json`` holds the bench's report, whose
``groups`` give per run ``step_ms_median``, ``plants_per_hour``, ``gpu_busy`` (null without
CUDA), ``host_core_ms_per_plant_step``, ``host_serial_ms_per_step``, ``peak_cuda_gib`` and
the rest, and ``resume``: a group of 4 with overlap on run straight through, and again
stopped by SIGINT after step ``--steps // 2`` and resumed; every plant's plant.ply and
images must be byte-identical (``--no-resume`` leaves it out). ``OUT/throughput.md`` is the bench's table.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import signal
import sys
from pathlib import Path
from typing import Any

BENCHES = Path(__file__).resolve().parent.parent / "benches"


def bench() -> Any:
    """benches/bench_throughput.py, which is not part of the package."""
    sys.path.insert(0, str(BENCHES))
    import bench_throughput

    return bench_throughput


def _hashes(folder: Path) -> dict[str, str]:
    names = ["plant.ply", *[str(p.relative_to(folder)) for p in sorted(folder.glob("*/*.png"))]]
    return {n: hashlib.sha256((folder / n).read_bytes()).hexdigest() for n in names}


def resume_check(args: argparse.Namespace, work: Path) -> dict[str, Any]:
    """A group of 4 (overlap on) straight, and stopped by SIGINT halfway and resumed."""
    from plantdreamer.guidance import StableDiffusionDepthGuidance
    from plantdreamer.pipeline import FolderPerPlant, GenerateConfig, RunInterrupted
    from plantdreamer.pipeline import generate_plants as train

    make = bench().build_parts(args)
    cfgs = [
        GenerateConfig.of(
            species="bean", seed=s, steps=args.steps, points=args.points,
            resolution=args.render, sds_resolution=args.sds, eval_views=2,
            turntable_frames=2, turntable="none", checkpoint_every=max(1, args.steps // 4),
            device=args.device, overlap="on",
        )
        for s in range(4)
    ]  # fmt: skip

    def guidance() -> Any:
        return StableDiffusionDepthGuidance(
            species="bean", components=make(), resolution=args.sds, device=args.device, seed=0
        )

    group = {"layout": FolderPerPlant(), "failures": "record", "show_progress": False}
    train(cfgs, work / "straight", guidance=guidance(), overwrite=True, **group)

    def ctrl_c(step: int) -> None:
        if step == args.steps // 2:
            os.kill(os.getpid(), signal.SIGINT)

    stopped = None
    try:
        train(cfgs, work / "cut", guidance=guidance(), overwrite=True, on_step=ctrl_c, **group)
    except RunInterrupted as stop:
        stopped = stop.step
    train(None, work / "cut", guidance=guidance(), resume=True, **group)
    names = [f"bean-s{s:04d}" for s in range(4)]
    same = {n: _hashes(work / "straight" / n) == _hashes(work / "cut" / n) for n in names}
    return {"stopped_at": stopped, "identical": same}


def run_throughput(argv: list[str]) -> int:
    b = bench()
    p = argparse.ArgumentParser(prog="gpu_checks.py throughput", description=__doc__.split("\n")[0])
    p.add_argument("out", type=Path, help="folder for throughput.json and throughput.md")
    b.add_arguments(p, gpu_checks=True)
    p.add_argument("--work", type=Path, default=Path("/tmp/plantdreamer-gpu-checks"))
    p.add_argument("--no-resume", action="store_true", help="leave out Ctrl-C + resume")
    p.add_argument("--only-resume", action="store_true", help="the Ctrl-C + resume check alone")
    args = p.parse_args(argv)
    b.resolve(args)
    from plantdreamer.atomic import write_json, write_text

    args.out.mkdir(parents=True, exist_ok=True)
    if args.trace is not None:
        b.trace_one(args)
    report: dict[str, Any] = {}
    if not args.only_resume:
        report = b.run_all(args)
        command = "python scripts/gpu_checks.py throughput " + " ".join(argv)
        write_text(args.out / "throughput.md", "\n".join(b.table(report, command.strip())) + "\n")
    ok = True
    if not args.no_resume:
        report["resume"] = resume_check(args, args.work / "throughput")
        ok = report["resume"]["stopped_at"] is not None and all(
            report["resume"]["identical"].values()
        )
    write_json(args.out / "throughput.json", report)
    if not args.only_resume:
        print((args.out / "throughput.md").read_text())
    print("resume:", report.get("resume", "not run"))
    return 0 if ok else 1
