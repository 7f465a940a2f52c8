"""``python scripts/gpu_checks.py all OUT [--baseline DIR] [--budget 470]``: the device
checks of the throughput work as one call that fits a time budget.

The checks run in order of what they decide, each as its own process with what is left of
the budget as its time limit; one that does not fit is recorded as not run (``OUT/all.json``
says which, with every check's seconds and exit status, and where its output is):

1. ``throughput-16``: B = 16 with overlap, the VAE in float32 and bfloat16, this tree and the
   ``--baseline`` package interleaved (a before/after under the same load);
2. ``known-answer-float32`` and ``known-answer-bfloat16``: the known answer on CUDA with the
   VAE in each precision (``scripts/known_answer.py --device cuda --vae-dtype ...``, the
   committed bean seed 0 models): bfloat16 must be within 0.3 dB of float32;
3. ``vae-precision``: the VAE's encode and backward alone at the half-batch of 8 in each
   dtype, memory format and attention kernel (``benches/bench_vae_precision.py``);
4. ``throughput-1-32``: B = 1 and B = 32 (overlap on), both precisions, this tree;
5. ``resume``: a group of 4 stopped by SIGINT halfway and resumed, byte-identical to the
   group run straight through (``gpu_throughput.resume_check``);
6. ``known-answer-render-96``: the known answer on CUDA training at 1.5x the SDS size (96
   against the models' 64, as 768 against 512), against ``known-answer-float32``'s 1x.

``--tiny`` makes every check a dry run on the CPU (tiny networks, small plants), as the
tests do.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# A check is not started with less than this left of the budget (it could not finish).
MIN_CHECK_S = 20.0
KNOWN_ANSWER_MODELS = ROOT / "tests" / "data" / "known_answer" / "bean_s0_r64"


def checks(args: argparse.Namespace, out: Path) -> list[tuple[str, list[str]]]:
    """(name, command) in the order they run."""
    py = sys.executable
    size = ["--tiny", "--points", "1500", "--render", "48", "--sds", "64", "--steps", "4",
            "--warmup", "2"] if args.tiny else ["--steps", "20", "--warmup", "8"]  # fmt: skip
    vaes = ["--vae", "float32"] if args.tiny else ["--vae", "float32", "bfloat16"]
    device = "cpu" if args.tiny else "cuda"
    baseline = ["--baseline", str(args.baseline)] if args.baseline else []
    throughput = [py, str(ROOT / "scripts" / "gpu_checks.py"), "throughput"]
    known = [py, str(ROOT / "scripts" / "known_answer.py"), "--models", str(KNOWN_ANSWER_MODELS),
             "--device", device] + (["--steps", "10"] if args.tiny else [])  # fmt: skip
    b16 = ["--groups", "2" if args.tiny else "16", "--overlap", "on"]
    b1_32 = ["--groups", "1", "3" if args.tiny else "32", "--overlap", "on"]
    vae_bench = [py, str(ROOT / "benches" / "bench_vae_precision.py")]
    vae_small = ["--tiny", "--batch", "2", "--reps", "2"] if args.tiny else []
    return [
        ("throughput-16",
         [*throughput, str(out / "throughput-16"), *b16, *vaes, *size, *baseline, "--no-resume"]),
        ("known-answer-float32",
         [*known, "--vae-dtype", "float32", "--json", str(out / "known-answer-float32.json")]),
        ("known-answer-bfloat16",
         [*known, "--vae-dtype", "bfloat16", "--json", str(out / "known-answer-bfloat16.json")]),
        ("vae-precision", [*vae_bench, "--out", str(out / "vae_precision.md"), *vae_small]),
        ("throughput-1-32",
         [*throughput, str(out / "throughput-1-32"), *b1_32, *vaes, *size, "--no-resume"]),
        ("resume",
         [*throughput, str(out / "resume"), "--only-resume", *size, "--work", str(args.work)]),
        ("known-answer-render-96",
         [*known, "--render", "96", "--json", str(out / "known-answer-render-96.json")]),
    ]  # fmt: skip


def run_all(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="gpu_checks.py all", description=__doc__.splitlines()[0])
    p.add_argument("out", type=Path)
    p.add_argument("--baseline", type=Path, help="an earlier package for the before/after")
    p.add_argument("--budget", type=float, default=470.0, help="seconds for every check")
    p.add_argument("--tiny", action="store_true", help="a dry run on the CPU")
    p.add_argument("--work", type=Path, default=Path("/tmp/plantdreamer-gpu-checks"))
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    report: dict = {"budget_s": args.budget, "checks": []}
    for name, cmd in checks(args, args.out):
        left = args.budget - (time.perf_counter() - start)
        entry: dict = {"name": name, "command": " ".join(cmd), "log": f"{name}.log"}
        if left < MIN_CHECK_S:
            entry["status"] = "not run: the budget was spent"
            report["checks"].append(entry)
            continue
        t0 = time.perf_counter()
        with (args.out / entry["log"]).open("w") as log:
            try:
                entry["rc"] = subprocess.run(
                    cmd, stdout=log, stderr=subprocess.STDOUT, timeout=left, cwd=ROOT
                ).returncode
                entry["status"] = "passed" if entry["rc"] == 0 else "failed"
            except subprocess.TimeoutExpired:
                entry["status"] = "stopped: the budget ran out"
        entry["seconds"] = time.perf_counter() - t0
        report["checks"].append(entry)
        print(f"{name}: {entry['status']} in {entry['seconds']:.0f} s", flush=True)
    report["known_answer_bfloat16_minus_float32_db"] = _known_answer_gap(args.out)
    (args.out / "all.json").write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report, indent=2))
    return 0 if all(c.get("status") == "passed" for c in report["checks"]) else 1


def _known_answer_gap(out: Path) -> float | None:
    """The bfloat16 run's masked PSNR at its last step minus the float32 run's (dB)."""
    try:
        scores = [
            json.loads((out / f"known-answer-{d}.json").read_text())["curve"][-1]["masked_psnr"]
            for d in ("bfloat16", "float32")
        ]
    except (OSError, KeyError, IndexError, ValueError):
        return None
    return float(scores[0] - scores[1])
