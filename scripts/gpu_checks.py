"""The checks that need a CUDA GPU, each one command (BENCHMARKS.md's GPU section cites them).

    python scripts/gpu_checks.py tests OUT                 # the CUDA tests (pytest)
    python scripts/gpu_checks.py resume OUT --steps 300    # Ctrl-C and --resume on CUDA
    python scripts/gpu_checks.py scaling OUT --binary BIN  # rasterizer stages vs threads
    python benches/bench_gpu.py --steps 200                # per-phase times, memory, projection
    python scripts/gpu_checks.py throughput OUT            # plants per hour in the steady
                                                           # state, B = 1, 8, 16, 32, overlap
                                                           # off / on, VAE float32 / bfloat16
    python scripts/gpu_checks.py throughput OUT --tiny --groups 4 --trace OUT/step.json
    python scripts/gpu_checks.py dataset OUT --steps 40    # `dataset --plants-per-gpu 4`
    python scripts/gpu_checks.py all OUT --baseline DIR    # the throughput work's checks in
                                                           # one call within --budget seconds

``throughput`` is ``scripts/gpu_throughput.py`` over ``benches/bench_throughput.py``:
several plants in one trainer, timed from step end to step end after warm-up.
``dataset`` is ``scripts/gpu_dataset.py``: the same through `plantdreamer dataset` on Ray.
``all`` is ``scripts/gpu_all.py``: B = 16 before and after (``--baseline``, an earlier
package), the known answer on CUDA with the VAE in float32 and bfloat16, the VAE alone in
each precision, B = 1 and 32, a group's Ctrl-C and resume, and the known answer rendering
at 1.5x the SDS size, in that order, each within what is left of ``--budget``.

``resume`` writes the full-size SD 2.1-base networks with random weights in the hub's folder
layout (``save_full_size_models``), so ``plantdreamer generate`` loads them through the real
loading code, then runs ``generate --guidance sds`` three times: once straight through, once
stopped with SIGINT (Ctrl-C) after its first checkpoint, and that run continued with
``--resume``. It reports each run's wall time and whether plant.ply and every rendered view
and mask of the resumed run are byte-identical to the straight run's (``OUT/resume.json``).

``scaling`` runs a prebuilt ``raster_timing`` binary (the host needs no cargo) at 1, 2, 4, 8
and 16 threads on 100k Gaussians at 512 and 768 and 1M at 768, forward and backward, and
writes each stage's time and the image and gradient hashes to ``OUT/scaling.json`` and
``OUT/scaling.md`` (``benches/thread_scaling.py``; about a minute on a 16-core host).
``--baseline OLD_BINARY`` interleaves a second build (before and after a change) and
``--rounds R`` repeats every run, alternating, for a host shared with other work.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

PYTHON = [sys.executable, "-m", "plantdreamer"]
ROOT = Path(__file__).resolve().parent.parent
# Ground truth and renders compared byte for byte; run.json and log.csv hold timings.
COMPARED = ("plant.ply", "transforms.json")
COMPARED_GLOBS = ("renders/*.png", "labels/*.png", "instances/*.png", "depth/*.png")


def run_tests(out: Path) -> int:
    tests = [
        "tests/test_gpu_path.py",
        "tests/test_raster_forward.py::test_cuda_inputs_round_trip",
        "tests/test_lora_train.py",
    ]
    log = out / "pytest.log"
    cmd = [sys.executable, "-m", "pytest", "-q", "-rs", *tests]
    with log.open("w") as f:
        rc = subprocess.call(cmd, stdout=f, stderr=subprocess.STDOUT)
    print(log.read_text()[-3000:])
    return rc


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def compared_files(root: Path) -> list[Path]:
    files = [root / name for name in COMPARED if (root / name).exists()]
    for pattern in COMPARED_GLOBS:
        files += sorted(root.glob(pattern))
    return [f.relative_to(root) for f in files]


def generate_args(args: argparse.Namespace, base: Path, control: Path, out: Path) -> list[str]:
    return [
        "generate", "--species", args.species, "--seed", "0", "--guidance", "sds",
        "--base-model", str(base), "--controlnet", str(control), "--device", args.device,
        "--steps", str(args.steps), "--checkpoint-every", str(args.checkpoint_every),
        "--eval-views", str(args.eval_views), "--turntable", "none", "--quiet",
        "--points", str(args.points), "--out", str(out),
    ] + [
        f"--{name}={value}"
        for name, value in (("resolution", args.resolution), ("sds-resolution", args.sds_resolution))
        if value is not None
    ]  # fmt: skip


def timed(cmd: list[str], log: Path) -> tuple[int, float]:
    t0 = time.perf_counter()
    with log.open("w") as f:
        rc = subprocess.call(cmd, stdout=f, stderr=subprocess.STDOUT)
    return rc, time.perf_counter() - t0


def run_resume(args: argparse.Namespace, out: Path) -> int:
    from plantdreamer.guidance.full_size import save_full_size_models
    from plantdreamer.guidance.tiny import save_tiny_models

    models = args.models
    base, control = models / "base", models / "controlnet"
    t0 = time.perf_counter()
    if not (base / "model_index.json").exists() or not (control / "config.json").exists():
        if args.tiny:  # a dry run of this script on a machine without a GPU
            save_tiny_models(models)
        else:
            save_full_size_models(models, seed=0, device=args.device)
    report: dict = {"models_s": time.perf_counter() - t0, "steps": args.steps}
    work = args.work
    full, cut = work / "full", work / "cut"
    shutil.rmtree(work, ignore_errors=True)

    rc, report["full_s"] = timed(
        [*PYTHON, *generate_args(args, base, control, full)], out / "full.log"
    )
    report["full_rc"] = rc
    if rc != 0:
        print((out / "full.log").read_text()[-3000:])
        return 1

    # Stopped with SIGINT a few seconds after its first checkpoint, as a user's Ctrl-C.
    t0 = time.perf_counter()
    with (out / "cut.log").open("w") as f:
        proc = subprocess.Popen(
            [*PYTHON, *generate_args(args, base, control, cut)], stdout=f, stderr=subprocess.STDOUT
        )
        checkpoint = cut / "checkpoint.pt"
        while proc.poll() is None and not checkpoint.exists():
            time.sleep(0.2)
        time.sleep(args.cut_after)
        proc.send_signal(signal.SIGINT)
        report["cut_rc"] = proc.wait()
    report["cut_s"] = time.perf_counter() - t0
    rows = (cut / "log.csv").read_text().strip().splitlines() if (cut / "log.csv").exists() else []
    report["cut_at_step"] = max(len(rows) - 1, 0)
    resume = [*PYTHON, "generate", "--resume", str(cut), "--quiet"]
    rc, report["resume_s"] = timed(resume, out / "resume.log")
    report["resume_rc"] = rc
    if rc != 0:
        print((out / "resume.log").read_text()[-3000:])
        return 1

    names = compared_files(full)
    different = [str(n) for n in names if (cut / n).read_bytes() != (full / n).read_bytes()]
    missing = [str(n) for n in compared_files(cut) if n not in set(names)]
    report.update(
        compared_files=len(names),
        different=different,
        only_in_resumed=missing,
        identical=not different and not missing and report["cut_rc"] == 130,
        plant_ply_sha256=sha256(full / "plant.ply"),
        run_json=json.loads((full / "run.json").read_text()),
    )
    (out / "resume.json").write_text(json.dumps(report, indent=2))
    summary = {k: v for k, v in report.items() if k != "run_json"}
    print(json.dumps(summary, indent=2))
    return 0 if report["identical"] else 1


def thread_scaling():
    """benches/thread_scaling.py, which is not part of the package."""
    sys.path.insert(0, str(ROOT / "benches"))
    import thread_scaling

    return thread_scaling


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["throughput"]:
        from gpu_throughput import run_throughput

        os.environ.setdefault("PLANTDREAMER_TRACEBACK", "1")
        return run_throughput(argv[1:])
    if argv[:1] == ["all"]:
        from gpu_all import run_all

        os.environ.setdefault("PLANTDREAMER_TRACEBACK", "1")
        return run_all(argv[1:])
    if argv[:1] == ["scaling"]:
        scaling = thread_scaling()
        sp = argparse.ArgumentParser(description="rasterizer stages against threads")
        sp.add_argument("out", type=Path, help="folder for scaling.json and scaling.md")
        scaling.add_arguments(sp)
        args = sp.parse_args(argv[1:])
        report = scaling.run_from_args(args.out, args)
        return 0 if report["identical_across_threads"] else 1
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("check", choices=("tests", "resume", "scaling", "dataset"))
    p.add_argument("out", type=Path, help="folder for logs and the JSON report")
    p.add_argument("--steps", type=int, help="steps per run (resume: 300, dataset: 40)")
    p.add_argument("--species", default="bean")
    p.add_argument("--device", default="cuda")
    p.add_argument("--checkpoint-every", type=int, default=100)
    p.add_argument("--cut-after", type=float, default=3.0, help="seconds after the checkpoint")
    p.add_argument("--eval-views", type=int, default=24)
    p.add_argument("--points", type=int, default=100_000)
    p.add_argument("--resolution", type=int, help="render size (default: generate's)")
    p.add_argument("--sds-resolution", type=int, help="SDS size (default: generate's)")
    p.add_argument("--tiny", action="store_true", help="tiny models (a dry run on the CPU)")
    p.add_argument("--models", type=Path, default=Path("/tmp/plantdreamer-full-size"))
    p.add_argument("--work", type=Path, default=Path("/tmp/plantdreamer-gpu-checks"))
    p.add_argument("--groups", type=int, nargs="+", help="B (dataset: 1 4)")
    p.add_argument("--plants", type=int, default=8, help="dataset: plants per run")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("PLANTDREAMER_TRACEBACK", "1")
    if args.check == "tests":
        return run_tests(args.out)
    if args.check == "dataset":
        args.steps = args.steps or 40
        args.resolution = args.resolution or (128 if args.tiny else 768)
        args.sds_resolution = args.sds_resolution or (64 if args.tiny else 512)
        if args.tiny and args.device == "cuda":
            args.device = "cpu"
        from gpu_dataset import run_dataset_check

        args.groups = args.groups or [1, 4]
        return run_dataset_check(args, args.out)
    args.steps = args.steps or 300
    return run_resume(args, args.out)


if __name__ == "__main__":
    sys.exit(main())
