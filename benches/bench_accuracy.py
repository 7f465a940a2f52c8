"""Time against error for the main job: masked PSNR of the real ``generate`` against the
known answer (docs/known_answer.md), over steps and seconds.

    python benches/bench_accuracy.py [--seeds 0,1,2] [--jobs N] [--cache DIR]
    python benches/bench_accuracy.py --from-json benches/results/accuracy.json
    python benches/bench_accuracy.py --replot   # the plot alone, from results/accuracy.md's table

For each plant seed, the known-answer models are built (or reused from the cache), then
``generate`` runs from each colour init (noise, black, white, original) at CFG 100, from
noise at CFG 7.5 and 20, with the VAE in bfloat16 and float16, in a group of two plants
(with and without overlap), and from noise for 600 steps with and without densification.
Each curve point is its own run (explicit schedule table: a shorter run is the first steps
of a longer one), so its seconds are a whole run's wall time. Writes
benches/results/accuracy.md, accuracy.json and docs/images/known_answer_accuracy.png.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import shlex
import statistics
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benches" / "results"
PLOT = ROOT / "docs" / "images" / "known_answer_accuracy.png"

SHORT = [0, 50, 100, 200]
# Density control first runs at step 400 (DensifyConfig: start 300, every 100), so the
# densify rows go to 600 steps: two rounds (400 and 500).
LONG = [0, 100, 200, 400, 600]
# (name, settings, curve)
CONFIGS: list[tuple[str, dict[str, Any], list[int]]] = [
    ("noise, CFG 100", {"color_init": "noise"}, SHORT),
    ("black, CFG 100", {"color_init": "black"}, SHORT),
    ("white, CFG 100", {"color_init": "white"}, SHORT),
    ("original, CFG 100", {"color_init": "original"}, SHORT),
    ("noise, CFG 20", {"color_init": "noise", "guidance_scale": 20.0}, SHORT),
    ("noise, CFG 7.5", {"color_init": "noise", "guidance_scale": 7.5}, SHORT),
    ("noise, CFG 100, untrained models", {"color_init": "noise", "untrained": True}, SHORT),
    # The VAE's precision (--vae-dtype): its backward makes the render gradients.
    ("noise, CFG 100, VAE bfloat16", {"color_init": "noise", "vae_dtype": "bfloat16"}, SHORT),
    ("noise, CFG 100, VAE float16", {"color_init": "noise", "vae_dtype": "float16"}, SHORT),
    # Trained first in a group with one companion (generate --seeds): one guidance call
    # for both plants per step, or one per plant with overlap (docs/scaling.md).
    ("noise, CFG 100, group of 2", {"color_init": "noise", "group": 2}, SHORT),
    (
        "noise, CFG 100, group of 2, overlap",
        {"color_init": "noise", "group": 2, "overlap": "on"},
        SHORT,
    ),
    ("noise, CFG 100, densify", {"color_init": "noise"}, LONG),
    ("noise, CFG 100, no densify", {"color_init": "noise", "densify_until": 0}, LONG),
]


def one_curve(job: tuple[int, int, str, str, int, int]) -> dict[str, Any]:
    resolution, seed, name, cache, threads, build_threads = job
    import torch

    torch.set_num_threads(threads)
    from plantdreamer.known_answer.build import cached_models, untrained_models
    from plantdreamer.known_answer.check import Truth, step_curve
    from plantdreamer.known_answer.spec import KnownAnswerSpec

    settings, curve = next((dict(s), c) for n, s, c in CONFIGS if n == name)
    # Settings go to generate by name (densify_until is --densify-until).
    spec = KnownAnswerSpec(seed=seed, resolution=resolution)
    if settings.pop("untrained", False):
        models = untrained_models(spec, Path(cache))
    else:
        models = cached_models(spec, Path(cache), threads=build_threads)
    with tempfile.TemporaryDirectory() as tmp:
        truth = Truth.of(spec, Path(tmp))
        scores = step_curve(spec, truth, models, Path(tmp), curve, **settings)
    curve_points = [vars(s) for s in scores]
    return {
        "seed": seed,
        "resolution": resolution,
        "models": models_label(spec),
        "config": name,
        "curve": curve_points,
    }


def models_label(spec: Any) -> str:
    """Which recipe made the models: a table may hold rows of more than one (the recipe
    changed and not every row was measured again)."""
    from plantdreamer.known_answer.spec import GENERATOR_VERSION

    return f"version {GENERATOR_VERSION}, VAE {spec.vae_steps} steps"


def build(job: tuple[int, int, str, int]) -> str:
    from plantdreamer.known_answer.build import cached_models
    from plantdreamer.known_answer.spec import KnownAnswerSpec

    resolution, seed, cache, threads = job
    spec = KnownAnswerSpec(seed=seed, resolution=resolution)
    return str(cached_models(spec, Path(cache), threads=threads))


def measure(
    resolution: int,
    seeds: list[int],
    jobs: int,
    cache: str,
    partial: Path | None = None,
    build_threads: int = 1,
    configs: list[str] | None = None,
    threads: int | None = None,
) -> list[dict[str, Any]]:
    """Every curve; each finished one is also appended to ``partial`` (JSON lines)."""
    from concurrent.futures import as_completed

    threads = threads or max(1, (os.cpu_count() or 1) // jobs)
    with ProcessPoolExecutor(max_workers=min(jobs, len(seeds))) as pool:
        list(pool.map(build, [(resolution, s, cache, build_threads) for s in seeds]))
    print("models built", file=sys.stderr, flush=True)
    names = [n for n, _, _ in CONFIGS if configs is None or n in configs]
    work = [(resolution, s, name, cache, threads, build_threads) for name in names for s in seeds]
    results = []
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for future in as_completed([pool.submit(one_curve, w) for w in work]):
            result = future.result()
            results.append(result)
            print(json.dumps(result), file=sys.stderr, flush=True)
            if partial is not None:
                with partial.open("a") as f:
                    f.write(json.dumps(result) + "\n")
    return results


def resolution_of(result: dict[str, Any]) -> int:
    return int(result.get("resolution", 64))  # results before --resolution were all 64 px


def set_of(result: dict[str, Any]) -> tuple[int, str]:
    """(px, models): runs are compared only within one such set."""
    return resolution_of(result), result["models"]


def sets_of(results: list[dict[str, Any]]) -> list[tuple[int, str]]:
    return sorted({set_of(r) for r in results})


def grouped(
    results: list[dict[str, Any]],
) -> list[tuple[str, int, str, list[dict[str, Any]]]]:
    """(run name, px, models, its seeds' results), in CONFIGS order within each set."""
    out = []
    for px, models in sets_of(results):
        for name, _, _ in CONFIGS:
            rows = [r for r in results if r["config"] == name and set_of(r) == (px, models)]
            if rows:
                out.append((name, px, models, rows))
    return out


def table(results: list[dict[str, Any]]) -> str:
    lines = [
        "| run | px | models | seeds | "
        + " | ".join(f"step {s}" for s in sorted({*SHORT, *LONG}))
        + " | s/100 steps |",
        "|---|---|---|---|" + "---|" * (len({*SHORT, *LONG}) + 1),
    ]
    for name, px, models, rows in grouped(results):
        cells = []
        for step in sorted({*SHORT, *LONG}):
            values = [p["masked_psnr"] for r in rows for p in r["curve"] if p["steps"] == step]
            if not values:
                cells.append("-")
            else:
                spread = (max(values) - min(values)) / 2
                shown = f"{statistics.mean(values):.2f}"
                cells.append(shown if len(values) == 1 else f"{shown} ± {spread:.2f}")
        per100 = [
            p["seconds"] * 100 / p["steps"] for r in rows for p in r["curve"] if p["steps"] == 100
        ]
        cells.append(f"{statistics.median(per100):.1f}" if per100 else "-")
        lines.append(f"| {name} | {px} | {models} | {len(rows)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# A point that gains less than this over the previous one: PSNR has stopped rising.
PLATEAU_DB = 0.25


def _mean_at(rows: list[dict[str, Any]], step: int) -> float | None:
    values = [p["masked_psnr"] for r in rows for p in r["curve"] if p["steps"] == step]
    return statistics.mean(values) if values else None


def _paired(
    results: list[dict[str, Any]], a: str, b: str, px: int, models: str
) -> list[tuple[Any, Any]]:
    """(run a, run b) of each seed measured in both, at size px with these models."""
    by = {(r["config"], r["seed"]): r for r in results if set_of(r) == (px, models)}
    return [(by[a, s], by[b, s]) for (n, s) in by if n == a and (b, s) in by]


def findings(results: list[dict[str, Any]]) -> list[str]:
    """What the table says about steps, densification, precision and groups, computed from
    the results (nothing here is typed in by hand)."""
    out = []
    for name, px, models, rows in grouped(results):
        if name != "noise, CFG 100, no densify":
            continue
        steps = sorted({p["steps"] for r in rows for p in r["curve"]})
        means = [(s, _mean_at(rows, s)) for s in steps]
        flat = next((a for (a, x), (_, y) in itertools.pairwise(means)
                     if x is not None and y is not None and y - x < PLATEAU_DB), None)  # fmt: skip
        shown = ", ".join(f"{m:.2f} at {s}" for s, m in means if m is not None)
        when = (f"stops rising (under {PLATEAU_DB} dB to the next point) after {flat} steps"
                if flat is not None else f"still rises at {steps[-1]} steps")  # fmt: skip
        out.append(f"- Steps a plant needs ({px} px, {models}, from noise, no densification, mean over "
                   f"{len(rows)} seeds: {shown} dB): PSNR {when}.")  # fmt: skip
    for px, models in sets_of(results):
        pairs = _paired(
            results, "noise, CFG 100, densify", "noise, CFG 100, no densify", px, models
        )
        if pairs:
            last = max(p["steps"] for p in pairs[0][0]["curve"])
            point = [
                [next(p for p in run["curve"] if p["steps"] == last) for run in pair]
                for pair in pairs
            ]
            dpsnr = [d["masked_psnr"] - n["masked_psnr"] for d, n in point]
            cost = [d["seconds"] / n["seconds"] for d, n in point]
            out.append(
                f"- Densification ({px} px, {models}, {last} steps, {len(pairs)} seeds): "
                f"{statistics.mean(d['gaussians'] for d, _ in point):,.0f} Gaussians against "
                f"{statistics.mean(n['gaussians'] for _, n in point):,.0f}, masked PSNR "
                f"{min(dpsnr):+.2f} to {max(dpsnr):+.2f} dB against none, in "
                f"{min(cost):.2f}-{max(cost):.2f} times the seconds."
            )
        for other, what in (
            ("noise, CFG 100, VAE bfloat16", "the VAE in bfloat16"),
            ("noise, CFG 100, VAE float16", "the VAE in float16"),
            ("noise, CFG 100, group of 2", "a group of 2"),
            ("noise, CFG 100, group of 2, overlap", "a group of 2 with overlap"),
        ):
            pairs = _paired(results, other, "noise, CFG 100", px, models)
            gaps = [
                abs(p["masked_psnr"] - q["masked_psnr"])
                for a, b in pairs
                for p, q in zip(a["curve"], b["curve"], strict=True)
            ]
            if gaps:
                # Two decimals would print a gap under 0.005 dB as "within 0.00".
                gap = f"{max(gaps):.2f}" if max(gaps) >= 0.005 else "0.005"
                out.append(f"- {what[0].upper() + what[1:]} ({px} px, {models}, {len(pairs)} seeds): "
                           f"within {gap} dB of the plain run at every point.")  # fmt: skip
    return out


# The plot's runs: at most six, so that each keeps a colour of its own; every run, and every
# size and model set, is in the table.
PLOTTED = [
    "noise, CFG 100",
    "original, CFG 100",
    "black, CFG 100",
    "white, CFG 100",
    "noise, CFG 7.5",
    "noise, CFG 100, untrained models",
]
Curve = tuple[str, list[int], list[float], float | None]


def curves(results: list[dict[str, Any]]) -> tuple[str, list[Curve]]:
    """The plotted runs of the first size and model set: (that set, [(run, steps, mean masked
    PSNR per step, median s/100 steps)]), the figures the table shows."""
    first = sets_of(results)[0]
    out: list[Curve] = []
    for name, px, models, rows in grouped(results):
        if name in PLOTTED and (px, models) == first:
            steps = sorted({p["steps"] for r in rows for p in r["curve"]})
            means = [m for m in (_mean_at(rows, s) for s in steps) if m is not None]
            per100 = [p["seconds"] for r in rows for p in r["curve"] if p["steps"] == 100]
            out.append((name, steps, means, statistics.median(per100) if per100 else None))
    return f"{first[0]} px, {first[1]}", sorted(out, key=lambda c: PLOTTED.index(c[0]))


def curves_from_table(text: str) -> tuple[str, list[Curve]]:
    """``curves`` read back from a written table (benches/results/accuracy.md): `--replot`
    redraws the plot from the committed figures, without the raw results."""
    rows = [line.strip("|").split("|") for line in text.splitlines() if line.startswith("|")]
    head = [c.strip() for c in rows[0]]
    step_cols = [
        (i, int(c.removeprefix("step "))) for i, c in enumerate(head) if c.startswith("step ")
    ]
    body = [[c.strip() for c in r] for r in rows[2:]]
    first = body[0][1], body[0][2]
    out: list[Curve] = []
    for r in body:
        if r[0] in PLOTTED and (r[1], r[2]) == first:
            cells = [(step, r[i].split(" ± ")[0]) for i, step in step_cols if r[i] != "-"]
            per100 = r[head.index("s/100 steps")]
            out.append((r[0], [c[0] for c in cells], [float(c[1]) for c in cells],
                        None if per100 == "-" else float(per100)))  # fmt: skip
    return f"{first[0]} px, {first[1]}", sorted(out, key=lambda c: PLOTTED.index(c[0]))


def plot(title: str, plotted: list[Curve], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    colours = plt.get_cmap("tab10")
    for k, (name, steps, means, per100) in enumerate(plotted):
        label = name + (f" ({per100:.1f} s/100 steps)" if per100 is not None else "")
        ax.plot(steps, means, label=label, color=colours(k), marker="o")
    # The true colours score 100 dB (exact) before any step; the axis is cut below that
    # so that the runs from wrong colours stay readable.
    ax.set_ylim(top=min(ax.get_ylim()[1], 45.0))
    ax.set(xlabel="SDS steps", ylabel="masked PSNR (dB), mean over seeds (cut at 45)")
    ax.set_title(f"The known answer, {title}", fontsize=9)
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def write(results: list[dict[str, Any]], machine: str, command: str) -> None:
    from plantdreamer.atomic import write_text

    seeds = sorted({r["seed"] for r in results})
    write_text(RESULTS / "accuracy.json", json.dumps({"machine": machine, "results": results}))
    plot(*curves(results), PLOT)
    text = f"""## Accuracy: the known answer over steps and seconds (`bench_accuracy.py`)

`{command}`, on {machine}. Masked PSNR (dB) of `generate` at the size given (px) against 16 held-out
true views of each plant (bean, seeds {", ".join(map(str, seeds))}: mean ± half the range
over seeds), each run scored by `plantdreamer eval`'s metric; models from
`scripts/known_answer.py` (docs/known_answer.md; "models": the generator version and the
VAE's training steps of the set the row was measured with). Seconds are whole `generate` runs
(model loading and export included) with the machine shared by parallel runs. Runs,
seeds and sizes missing from the table were not measured in this run (the command says
which were asked for); docs/known_answer.md says what these models can and cannot show.

{table(results)}

What it says:

{chr(10).join(findings(results))}

![masked PSNR against steps, six of the runs](docs/images/known_answer_accuracy.png)
"""
    write_text(RESULTS / "accuracy.md", text)


def machine_line() -> str:
    import torch
    from host import host_line

    # torch's CPU capability too: the models a bench builds differ in their bits from one
    # CPU to another (docs/known_answer.md, "Bits and CPUs").
    return (
        f"{host_line()}, torch CPU capability {torch.backends.cpu.get_cpu_capability()}, "
        f"torch {torch.__version__}"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--resolution", type=int, default=64, help="Render and SDS size (px).")
    p.add_argument("--jobs", type=int, default=max(1, (os.cpu_count() or 2) // 2))
    p.add_argument("--cache", default=None)
    p.add_argument(
        "--threads", type=int, help="CPU threads per run (default: the cores over --jobs)."
    )
    p.add_argument("--json", type=Path, help="Also write the raw results here.")
    p.add_argument("--partial", type=Path, help="Append each finished curve here.")
    p.add_argument("--configs", help="Only these runs (names as in the table, ';'-separated).")
    p.add_argument(
        "--build-threads",
        type=int,
        default=1,
        help="CPU threads per model build (1: the "
        "bits scripts/known_answer.py makes; more: faster, other bits).",
    )
    p.add_argument("--from-json", type=Path, help="Only rewrite the table and plot from this.")
    p.add_argument(
        "--replot", action="store_true", help="Only redraw the plot from results/accuracy.md."
    )
    args = p.parse_args(argv)
    if args.replot:
        plot(*curves_from_table((RESULTS / "accuracy.md").read_text()), PLOT)
        return 0
    if args.from_json is not None:
        data = json.loads(args.from_json.read_text())
        write(data["results"], data["machine"], data["command"])
        return 0
    from plantdreamer.known_answer.build import default_cache

    seeds = [int(s) for s in args.seeds.split(",")]
    cache = args.cache or str(default_cache())
    configs = None if args.configs is None else [c.strip() for c in args.configs.split(";")]
    unknown = set(configs or []) - {n for n, _, _ in CONFIGS}
    if unknown:
        p.error(f"unknown runs: {', '.join(sorted(unknown))}")
    results = measure(
        args.resolution,
        seeds,
        args.jobs,
        cache,
        args.partial,
        args.build_threads,
        configs,
        args.threads,
    )
    command = shlex.join(["python", "benches/bench_accuracy.py", *(argv or sys.argv[1:])])
    if args.json is not None:
        args.json.write_text(
            json.dumps({"machine": machine_line(), "command": command, "results": results})
        )
    write(results, machine_line(), command)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
