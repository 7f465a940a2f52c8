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
    python benches/bench_throughput.py --groups 4 --overlap 4   # overlap off / on, B = 4
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


def one_group(b: int, args: argparse.Namespace, overlap: str = "off") -> dict[str, float]:
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


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--groups", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--steps", type=int, default=6)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--points", type=int, default=10_000)
    parser.add_argument("--render", type=int, default=128)
    parser.add_argument("--sds", type=int, default=64)
    parser.add_argument("--overlap", type=int, nargs="*", default=[4], help="B with overlap on")
    parser.add_argument("--out", type=Path, default=RESULTS / "throughput.md")
    args = parser.parse_args()
    variants = [(b, "off") for b in args.groups] + [(b, "on") for b in args.overlap]
    runs: dict[tuple[int, str], list[dict[str, float]]] = {v: [] for v in variants}
    for _ in range(args.repeats):  # interleaved: each repeat runs every variant once
        for b, overlap in variants:
            runs[b, overlap].append(one_group(b, args, overlap))
    rows, results_of = [], {}
    for (b, overlap), results in runs.items():
        row: dict[str, object] = {"B": b if overlap == "off" else f"{b}, overlap on"}
        results_of[row["B"]] = results
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
        per_hour = [r["plants_per_hour"] for r in results_of[row["B"]]]
        lines.append(
            f"| {row['B']} | {step[0]:.1f} / {step[1]:.1f} | " + " | ".join(cells)
            + f" | {statistics.median(per_hour):.2f} (best {max(per_hour):.2f}) |"
        )  # fmt: skip
    args.out.write_text("\n".join(lines) + "\n")
    record = {
        "args": {**vars(args), "out": str(args.out)},
        "runs": results_of,
    }
    args.out.with_suffix(".json").write_text(json.dumps(record, indent=2))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
