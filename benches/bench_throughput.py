"""Plants per hour with several plants in one trainer (`generate --seeds`), B = 1, 2, 4, 8.

Tiny random-weight diffusion models on this machine's CPU (no CUDA GPU here): the UNet
costs far less than SD 2.1's, so the figures show the host side of a group step (B renders
and rasterizer backwards on B threads, the batched guidance call, per-plant Adam and
density control), not a GPU's. Each B runs as one group of B plants (L-System bean,
seeds 0..B-1) for a few steps; the B values are interleaved over the repeats, and the
min and median are reported. "plants per hour" projects the measured training time per
plant-step to 3600-step plants (preparation and export excluded: they are per plant and
do not change with B).

    python benches/bench_throughput.py                     # B = 1, 2, 4, 8; 6 steps; 3 repeats
    python benches/bench_throughput.py --groups 1 2 --steps 4 --repeats 1 --render 64
    python benches/bench_throughput.py --loading 8     # model loading per plant vs per worker

``--loading N`` measures what a dataset worker pays to get each plant's guidance, for N
plants: with the models loaded for every plant (a new ``dataset.worker.ModelCache`` per
plant, as one Ray task per plant did) and once per worker (one cache for all N, as a
``PlantWorker`` does). Tiny models saved to disk in the hub's layout, so the load is a
real ``from_pretrained``; the two ways alternate over the repeats.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
PHASES = ("render", "depth", "guidance", "backward", "optimizer")
STEPS_PER_PLANT = 3600


def one_group(b: int, args: argparse.Namespace) -> dict[str, float]:
    from plantdreamer.guidance.sds import StableDiffusionDepthGuidance
    from plantdreamer.guidance.tiny import tiny_models
    from plantdreamer.pipeline import GenerateConfig
    from plantdreamer.pipeline.group import generate_group

    cfgs = [
        GenerateConfig.of(
            species="bean", seed=s, steps=args.steps, points=args.points,
            resolution=args.render, eval_views=1, turntable_frames=1, turntable="none",
        )
        for s in range(b)
    ]  # fmt: skip
    guidance = StableDiffusionDepthGuidance(
        species="bean", components=tiny_models(), resolution=args.sds, seed=0
    )
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        result = generate_group(cfgs, tmp, guidance=guidance, show_progress=False)
        wall = time.perf_counter() - t0
        assert not result.failed, result.failed
        timings = json.loads((Path(tmp) / "bean-s0000" / "run.json").read_text())["timings_s"]
    train = sum(timings.get(k, 0.0) for k in PHASES)  # the group's step phases (shared)
    out = {f"{k}_ms": 1000 * timings.get(k, 0.0) / args.steps for k in PHASES}
    out["step_ms"] = 1000 * train / args.steps
    out["plants_per_hour"] = 3600 * b / (train / args.steps * STEPS_PER_PLANT)
    out["wall_s"] = wall
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
    parser.add_argument("--out", type=Path, default=RESULTS / "throughput.md")
    args = parser.parse_args()
    if args.loading:
        lines = loading(args)
        args.out.with_name("throughput_loading.md").write_text("\n".join(lines) + "\n")
        print("\n".join(lines))
        return 0
    runs: dict[int, list[dict[str, float]]] = {b: [] for b in args.groups}
    for _ in range(args.repeats):  # interleaved: each repeat runs every B once
        for b in args.groups:
            runs[b].append(one_group(b, args))
    rows = []
    for b, results in runs.items():
        row: dict[str, object] = {"B": b}
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
        "are the group's (one step trains B plants); plants per hour projects them to "
        f"{STEPS_PER_PLANT}-step plants.",
        "",
        "| B | step ms | " + " | ".join(f"{p} ms" for p in PHASES) + " | plants per hour |",
        "|---|---|" + "---|" * len(PHASES) + "---|",
    ]
    for row in rows:
        cells = [f"{row[f'{p}_ms'][0]:.1f} / {row[f'{p}_ms'][1]:.1f}" for p in PHASES]
        step = row["step_ms"]
        per_hour = [r["plants_per_hour"] for r in runs[row["B"]]]
        lines.append(
            f"| {row['B']} | {step[0]:.1f} / {step[1]:.1f} | " + " | ".join(cells)
            + f" | {statistics.median(per_hour):.2f} (best {max(per_hour):.2f}) |"
        )  # fmt: skip
    args.out.write_text("\n".join(lines) + "\n")
    record = {"args": {**vars(args), "out": str(args.out)}, "runs": runs}
    args.out.with_suffix(".json").write_text(json.dumps(record, indent=2))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
