"""Plants per hour with several plants in one trainer (`generate --seeds`), B = 1, 2, 4, 8.

Tiny random-weight diffusion models on this machine's CPU (no CUDA GPU here): the UNet
costs far less than SD 2.1's, so the figures show the host side of a group step (B renders
and rasterizer backwards on B threads, the batched guidance call, per-plant Adam and
density control), not a GPU's. Each B runs as one group of B plants (L-System bean,
seeds 0..B-1) for a few steps; the B values are interleaved over the repeats, and the
min and median are reported. "plants per hour" projects the measured training time per
plant-step to 3600-step plants (preparation and export excluded: they are per plant and
do not change with B). ``--overlap`` adds rows of those B trained as two halves in flight
(``overlap on``; the other rows are ``off``), interleaved with the rest.

    python benches/bench_throughput.py                     # B = 1, 2, 4, 8; 6 steps; 3 repeats
    python benches/bench_throughput.py --groups 1 2 --steps 4 --repeats 1 --render 64
    python benches/bench_throughput.py --separate      # and B processes of one plant each
    python benches/bench_throughput.py --loading 8     # model loading per plant vs per worker

Each row also gives the host's core use (process CPU time / wall / cores) and, on CUDA, the
GPU's idle share of the wall time (the union of the kernels' intervals from the profiler's
CUDA events; on this machine, which has no CUDA GPU, that column says not measured).
``--separate`` adds, for each B, B processes side by side that train one plant each on
cores / B threads (as `dataset` without packing runs B plants sharing a GPU).

``--loading N`` measures what a dataset worker pays to get each plant's guidance, for N
plants: with the models loaded for every plant (a new ``dataset.worker.ModelCache`` per
plant, as one Ray task per plant did) and once per worker (one cache for all N, as a
``PlantWorker`` does). Tiny models saved to disk in the hub's layout, so the load is a
real ``from_pretrained``; the two ways alternate over the repeats.
    python benches/bench_throughput.py --groups 4 --overlap 4   # overlap off / on, B = 4
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
PHASES = ("render", "depth", "guidance", "backward", "optimizer")
STEPS_PER_PLANT = 3600
OVERLAPPED = "one trainer, two halves in flight"


def one_group(
    b: int, args: argparse.Namespace, first_seed: int = 0, overlap: str = "off"
) -> dict[str, float]:
    from plantdreamer.guidance.sds import StableDiffusionDepthGuidance
    from plantdreamer.guidance.tiny import tiny_models
    from plantdreamer.pipeline import GenerateConfig
    from plantdreamer.pipeline.group import generate_group

    cfgs = [
        GenerateConfig.of(
            species="bean", seed=s, steps=args.steps, points=args.points,
            resolution=args.render, eval_views=1, turntable_frames=1, turntable="none",
            overlap=overlap,
        )
        for s in range(first_seed, first_seed + b)
    ]  # fmt: skip
    guidance = StableDiffusionDepthGuidance(
        species="bean", components=tiny_models(), resolution=args.sds, seed=first_seed
    )
    with tempfile.TemporaryDirectory() as tmp, gpu_busy() as busy:
        t0, cpu0 = time.perf_counter(), time.process_time()
        result = generate_group(cfgs, tmp, guidance=guidance, show_progress=False)
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
        assert not result.failed, result.failed
        first = f"bean-s{first_seed:04d}"
        timings = json.loads((Path(tmp) / first / "run.json").read_text())["timings_s"]
    train = sum(timings.get(k, 0.0) for k in PHASES)  # the group's step phases (shared)
    out = {f"{k}_ms": 1000 * timings.get(k, 0.0) / args.steps for k in PHASES}
    out["step_ms"] = 1000 * train / args.steps
    out["plants_per_hour"] = 3600 * b / (train / args.steps * STEPS_PER_PLANT)
    out["wall_s"] = wall
    out["core_use"] = cpu / (wall * (os.cpu_count() or 1))  # the host's cores kept busy
    if busy:
        out["gpu_idle"] = 1.0 - busy[0] / wall
    return out


@contextlib.contextmanager
def gpu_busy() -> Iterator[list[float]]:
    """On CUDA, yields a list that gets the seconds some kernel ran on the GPU during the
    block (the union of the kernels' intervals, from the profiler's CUDA events); on the
    CPU an empty list."""
    import torch

    busy: list[float] = []
    if not torch.cuda.is_available():
        yield busy
        return
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CUDA]) as prof:
        yield busy
        torch.cuda.synchronize()
    spans = sorted(
        (e.time_range.start, e.time_range.end)
        for e in prof.events()
        if e.device_type == torch.autograd.DeviceType.CUDA
    )
    total, end = 0.0, float("-inf")
    for start, stop in spans:  # microseconds; overlapping kernels counted once
        if stop > end:
            total += stop - max(start, end)
            end = stop
    busy.append(total / 1e6)


def separate(b: int, args: argparse.Namespace) -> dict[str, float]:
    """B plants as B processes side by side, one plant each, the cores split between them
    (as `dataset` gives each plant its CPUs): plants per hour added over the processes."""
    cores = os.cpu_count() or 1
    threads = str(max(1, cores // b))
    env = {**os.environ, "RAYON_NUM_THREADS": threads, "OMP_NUM_THREADS": threads}
    cmd = [sys.executable, __file__, "--steps", str(args.steps), "--points", str(args.points),
           "--render", str(args.render), "--sds", str(args.sds), "--child"]  # fmt: skip
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    procs = [subprocess.Popen([*cmd, str(s)], env=env, stdout=subprocess.PIPE, text=True)
             for s in range(b)]  # fmt: skip
    children = [json.loads(p.communicate()[0].strip().splitlines()[-1]) for p in procs]
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    out = {k: max(c[k] for c in children) for k in children[0] if k.endswith("_ms")}
    out["plants_per_hour"] = sum(c["plants_per_hour"] for c in children)
    out["wall_s"] = wall
    out["core_use"] = cpu / (wall * cores)
    return out


def guidance_times(n: int, folder: Path, shared: bool) -> list[float]:
    """Seconds to build each of ``n`` plants' guidance (tiny models from ``folder``)."""
    from plantdreamer.dataset.worker import ModelCache
    from plantdreamer.pipeline import GenerateConfig
    from plantdreamer.pipeline.runtime import resolve_runtime

    cache, times = ModelCache(), []
    for seed in range(n):
        cfg = GenerateConfig.of(
            species="bean", seed=seed, base_model=str(folder / "base"),
            controlnet=str(folder / "controlnet"), device="cpu", sds_resolution=64,
        )  # fmt: skip
        resolve_runtime(cfg)
        if not shared:
            cache = ModelCache()
        t0 = time.perf_counter()
        cache.guidance_for(cfg)
        times.append(time.perf_counter() - t0)
    return times


def loading(args: argparse.Namespace) -> list[str]:
    from plantdreamer.guidance.tiny import save_tiny_models

    runs: dict[str, list[float]] = {"per plant": [], "once per worker": []}
    totals: dict[str, list[float]] = {k: [] for k in runs}
    with tempfile.TemporaryDirectory() as tmp:
        save_tiny_models(tmp)
        guidance_times(1, Path(tmp), shared=False)  # imports and file cache warm
        for _ in range(args.repeats):
            for name in runs:
                times = guidance_times(args.loading, Path(tmp), shared=name != "per plant")
                runs[name] += times
                totals[name].append(sum(times))
    command = "python benches/bench_throughput.py " + " ".join(sys.argv[1:])
    lines = [
        "## Model loading per plant and per worker (`benches/bench_throughput.py --loading`)",
        "",
        f"Command: `{command.strip()}`, on {os.cpu_count()} shared CPU cores, no CUDA GPU on "
        f"the benchmark machine. Building the guidance of {args.loading} plants (tiny "
        "random-weight models saved in the hub's layout, CPU, float32), the two ways "
        f"alternating over {args.repeats} repeats; min / median.",
        "",
        f"| models loaded | per plant, ms | all {args.loading} plants, s |",
        "|---|---|---|",
    ]
    for name, times in runs.items():
        per = f"{1000 * min(times):.1f} / {1000 * statistics.median(times):.1f}"
        total = f"{min(totals[name]):.2f} / {statistics.median(totals[name]):.2f}"
        lines.append(f"| {name} | {per} | {total} |")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--groups", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--steps", type=int, default=6)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--points", type=int, default=10_000)
    parser.add_argument("--render", type=int, default=128)
    parser.add_argument("--sds", type=int, default=64)
    parser.add_argument("--loading", type=int, metavar="N", help="plants of the loading bench")
    parser.add_argument("--separate", action="store_true", help="also B processes of 1 plant")
    parser.add_argument("--overlap", type=int, nargs="*", default=[4], help="B with overlap on")
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)  # one plant, JSON out
    parser.add_argument("--out", type=Path, default=RESULTS / "throughput.md")
    args = parser.parse_args()
    if args.loading:
        lines = loading(args)
        args.out.with_name("throughput_loading.md").write_text("\n".join(lines) + "\n")
        print("\n".join(lines))
        return 0
    if args.child is not None:
        print(json.dumps(one_group(1, args, first_seed=args.child)))
        return 0
    modes = ["one trainer", *(["B processes"] if args.separate else [])]
    variants = [(b, m) for b in args.groups for m in modes]
    variants += [(b, OVERLAPPED) for b in args.overlap]
    runs: dict[tuple[int, str], list[dict[str, float]]] = {v: [] for v in variants}
    for _ in range(args.repeats):  # interleaved: each repeat runs every B and mode once
        for b, mode in runs:
            if mode == "B processes":
                runs[b, mode].append(separate(b, args))
            else:
                overlap = "on" if mode == OVERLAPPED else "off"
                runs[b, mode].append(one_group(b, args, overlap=overlap))
    rows = []
    for (b, mode), results in runs.items():
        row: dict[str, object] = {"B": b, "mode": mode}
        for key in results[0]:
            values = [r[key] for r in results]
            row[key] = (min(values), statistics.median(values))
        rows.append(row)
    command = "python benches/bench_throughput.py " + " ".join(sys.argv[1:])
    lines = [
        "## Several plants in one trainer (`benches/bench_throughput.py`)",
        "",
        f"Command: `{command.strip()}`, on {os.cpu_count()} shared CPU cores (other jobs ran "
        "beside it: the spread between min and median is theirs), no CUDA GPU on the "
        "benchmark machine, so these are the host side with tiny random-weight networks, "
        "not the 30-plants-per-hour goal's full-size CUDA figures (not measured). L-System bean, "
        f"{args.points} points, {args.render} px renders, tiny SDS at {args.sds} px, "
        f"{args.steps} steps, {args.repeats} interleaved repeats (min / median). Step phases "
        "are the group's (one step trains B plants; B processes: the slowest process's); "
        f"plants per hour projects them to {STEPS_PER_PLANT}-step plants (B processes: "
        "added over the processes, each on cores / B threads). Core use is process CPU "
        "time / wall / cores (median); GPU idle, on CUDA only, is the share of the wall "
        "time in which no kernel ran (profiler CUDA events).",
        "",
        "| B | mode | step ms | " + " | ".join(f"{p} ms" for p in PHASES)
        + " | plants per hour | core use | GPU idle |",
        "|---|---|---|" + "---|" * len(PHASES) + "---|---|---|",
    ]  # fmt: skip
    for row in rows:
        cells = [f"{row[f'{p}_ms'][0]:.1f} / {row[f'{p}_ms'][1]:.1f}" for p in PHASES]
        step = row["step_ms"]
        done = runs[row["B"], row["mode"]]  # type: ignore[index]
        per_hour = [r["plants_per_hour"] for r in done]
        idle = [r["gpu_idle"] for r in done if "gpu_idle" in r]
        idle_text = f"{statistics.median(idle):.2f}" if idle else "not measured (no CUDA)"
        lines.append(
            f"| {row['B']} | {row['mode']} | {step[0]:.1f} / {step[1]:.1f} | " + " | ".join(cells)
            + f" | {statistics.median(per_hour):.2f} (best {max(per_hour):.2f})"
            + f" | {statistics.median(r['core_use'] for r in done):.2f} | {idle_text} |"
        )  # fmt: skip
    args.out.write_text("\n".join(lines) + "\n")
    record = {"args": {**vars(args), "out": str(args.out)},
              "runs": {f"{b} {m}": r for (b, m), r in runs.items()}}  # fmt: skip
    args.out.with_suffix(".json").write_text(json.dumps(record, indent=2))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
