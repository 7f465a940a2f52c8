"""Rasterizer roofline: the blending work per call against this CPU's measured vector peak.
Writes benches/results/roofline.md (+ roofline.json).

    python benches/bench_roofline.py [--reps N] [--threads T] [--rounds R] [--baseline BIN]

Runs two release examples of splat_core, without Python in the timed calls:
- `fma_peak`: tight loops of independent AVX2 fused multiply-adds (AVX-512 where the CPU
  has it) and of separate multiplies and adds, the blending kernels' instruction mix;
- `raster_timing` with `EVALS=1 BACKWARD=1` on the bench scene (100k Gaussians) and on a
  dense one (450k, >= 500k tile intersections at 512^2 with the default tiles): min and
  median per stage, and the pixel-splat evaluations the blends perform
  (`raster::count_evaluations`, counted outside the timed calls).

With `--baseline BIN` (a `raster_timing` built from an earlier commit), it also times BIN and
the current build alternately, R rounds each, on both scenes: on a shared machine whose
speed swings, only calls interleaved in the same run compare.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

BENCHES = Path(__file__).resolve().parent
ROOT = BENCHES.parent
RESULTS = BENCHES / "results"
sys.path.insert(0, str(BENCHES))

from raster_scene import dump  # noqa: E402

COMMAND = "python benches/bench_roofline.py"
SIZE = 512
# (name, Gaussians): the bench scene and a densified plant.
SCENES = [("bench", 100_000), ("dense", 450_000)]
# The backward target holds on a dense scene of at least this many intersections.
DENSE_INTERSECTIONS = 500_000
LANES = 8
MIN_CALLS_PER_RUN = 10
# Vector floating-point instructions (add, sub, mul, div, min, max, compare) per lane group
# of 8 pixels in the AVX2 kernels of crates/splat_core/src/raster/blend_avx2.rs with 3
# channels, counted in the source (bitwise masks, blends, integer ops, loads and stores
# not included); docs/rasterizer.md lists them.
FP_OPS_PER_GROUP = {"forward": 42, "backward": 89}


def examples_dir() -> Path:
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    return target / "release" / "examples"


def build() -> None:
    cmd = ["cargo", "build", "--release", "-q", "-p", "splat_core"]
    subprocess.run([*cmd, "--example", "fma_peak", "--example", "raster_timing"], check=True)


def run(args: list[str], env: dict[str, str] | None = None) -> str:
    full_env = {**os.environ, **(env or {})}
    return subprocess.run(args, check=True, capture_output=True, text=True, env=full_env).stdout


def fma_peak(threads: int) -> list[dict]:
    out = run([str(examples_dir() / "fma_peak"), str(threads), "3"])
    rows = []
    for m in re.finditer(
        r"^(\S+) (\S+) threads (\d+): ([\d.]+) G instr/s, ([\d.]+) G lane-ops/s", out, re.M
    ):
        rows.append(
            {
                "loop": m[1],
                "isa": m[2],
                "threads": int(m[3]),
                "ginstr_s": float(m[4]),
                "glane_s": float(m[5]),
            }
        )
    if "avx512: absent" in out:
        rows.append({"loop": "fma", "isa": "avx512", "absent": True})
    return rows


def current_binary() -> str:
    return str(examples_dir() / "raster_timing")


def timing_run(binary: str, scene: Path, threads: int, reps: int, count: bool = False) -> dict:
    """One `raster_timing` run: min and median per stage; with `count`, also the
    intersections and the blending work."""
    out = run(
        [binary, str(scene), str(threads), str(reps)],
        {"BACKWARD": "1", **({"EVALS": "1"} if count else {})},
    )
    res: dict = {"stages": {}}
    for m in re.finditer(r"^\s*(\w+(?: cpu)?) ms: min ([\d.]+) median ([\d.]+)", out, re.M):
        res["stages"][m[1]] = (float(m[2]), float(m[3]))
    if count:
        res["intersections"] = int(re.search(r"^intersections (\d+)", out, re.M)[1])
        for m in re.finditer(r"^(forward|backward) evaluations (\d+) blended (\d+)", out, re.M):
            res[m[1]] = {"evaluated": int(m[2]), "blended": int(m[3])}
    return res


def merged_stages(runs: list[dict]) -> dict:
    """Per stage over several runs: min over all calls, median of the runs' medians."""
    return {
        s: (
            min(r["stages"][s][0] for r in runs),
            statistics.median(r["stages"][s][1] for r in runs),
        )
        for s in runs[0]["stages"]
    }


def calls_per_run(reps: int, rounds: int) -> int:
    """Timed calls per `raster_timing` run of a stage row. Short runs read high: before
    `raster_timing` made an untimed first call, 4-call runs' best forward was 21.7 ms where
    12-call runs' was 18.3 (bench scene, 2 threads, interleaved)."""
    return max(reps // rounds, MIN_CALLS_PER_RUN)


def stage_rows(scenes: list[tuple[str, int, Path]], threads: list[int], reps: int, rounds: int):
    """Every (scene, threads) row timed in `rounds` rounds of `calls_per_run` calls, the rows
    taking turns within a round (`merged_stages`). Runs spread over time catch fewer of a
    shared machine's slow spells than one long run per row."""
    keys = [(name, n, path, t) for name, n, path in scenes for t in threads]
    runs: dict[tuple, list[dict]] = {k: [] for k in keys}
    calls = calls_per_run(reps, rounds)
    for r in range(rounds):
        for k in keys:
            runs[k].append(timing_run(current_binary(), k[2], k[3], calls, count=r == 0))
    return [
        {"scene": name, "n": n, "threads": t, **rs[0], "stages": merged_stages(rs)}
        for (name, n, _, t), rs in runs.items()
    ]


def interleaved(path: Path, baseline: str, threads: int, reps: int, rounds: int) -> dict:
    """Per binary (`merged_stages`): forward and backward, wall-clock and CPU time (all
    threads; it leaves out the time other work holds the cores, so it compares builds more
    steadily on a loaded machine)."""
    binaries = {"baseline": baseline, "current": current_binary()}
    runs: dict[str, list[dict]] = {key: [] for key in binaries}
    for _ in range(rounds):
        for key, binary in binaries.items():
            runs[key].append(timing_run(binary, path, threads, reps))
    return {key: merged_stages(rs) for key, rs in runs.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=20)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--baseline", help="raster_timing built from an earlier commit")
    parser.add_argument("--rounds", type=int, default=4, help="runs per row and per build")
    parser.add_argument("--baseline-label", help="what the baseline is, for the report")
    args = parser.parse_args()
    build()
    peaks = fma_peak(args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        scenes = []
        for name, n in SCENES:
            path = Path(tmp) / f"{name}.bin"
            dump(str(path), n, SIZE)
            scenes.append((name, n, path))
        runs = stage_rows(scenes, sorted({1, args.threads}), args.reps, args.rounds)
        compare = []
        for name, n, path in scenes if args.baseline else []:
            res = interleaved(path, args.baseline, args.threads, args.reps // 2, args.rounds)
            compare.append({"scene": name, "n": n, **res})
    RESULTS.mkdir(exist_ok=True)
    data = {"peaks": peaks, "runs": runs, "compare": compare}
    (RESULTS / "roofline.json").write_text(json.dumps(data, indent=1))
    (RESULTS / "roofline.md").write_text(report(peaks, runs, compare, args))


def targets(runs: list[dict], threads: int) -> list[str]:
    """Issue 20's targets against this run's minima."""
    by = {(r["scene"], r["threads"]): r for r in runs}
    if ("bench", threads) not in by or ("dense", threads) not in by:
        return []
    bench, dense = by["bench", threads]["stages"], by["dense", threads]["stages"]
    isects = by["dense", threads]["intersections"]
    fw = bench["forward"][0]
    ratios = [s["backward"][0] / s["forward"][0] for s in (bench, dense)]

    def met(ok: bool) -> str:
        return "met" if ok else "not met"

    return [
        f"Targets: forward, 100k at 512^2 on {threads} threads, <= 8 ms (best call): "
        f"{fw:.1f} ms in this run ({met(fw <= 8.0)}). Backward <= 1.3x forward on both "
        f"scenes: {ratios[0]:.2f} (bench) and {ratios[1]:.2f} (dense, {isects:,} intersections, "
        f"at least {DENSE_INTERSECTIONS:,} required) "
        f"({met(max(ratios) <= 1.3 and isects >= DENSE_INTERSECTIONS)}). "
        "Both as measured here, under the load below.",
    ]


def report(
    peaks: list[dict], runs: list[dict], compare: list[dict], args: argparse.Namespace
) -> str:
    cpu_flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    isa = "AVX-512F" if " avx512f" in cpu_flags else "AVX2 + FMA (no AVX-512)"
    lines = [
        "## Rasterizer roofline",
        "",
        f"Command: `{COMMAND} --reps {args.reps} --threads {args.threads} --rounds {args.rounds}"
        f"{' --baseline BIN' if args.baseline else ''}` (release examples "
        "`fma_peak` and `raster_timing`, no Python in the timed calls). "
        f"Scenes: `benches/raster_scene.py` at {SIZE}^2, one camera. CPU vector ISA: {isa}.",
        "",
        "### Ceiling: measured vector peak",
        "",
        "Best of repeated 2M-iteration loops over 12 independent accumulators. The blending "
        "kernels use separate multiplies and adds (no FMA, so every path gives the same bits): "
        "the `mul+add` row is their ceiling.",
        "",
        "| loop | ISA | threads | G vector instr/s | G f32 lane-ops/s |",
        "|---|---|---:|---:|---:|",
    ]
    for p in peaks:
        if p.get("absent"):
            lines.append(f"| {p['loop']} | {p['isa']} | - | absent on this CPU | - |")
        else:
            lines.append(
                f"| {p['loop']} | {p['isa']} | {p['threads']} | {p['ginstr_s']:.2f} | "
                f"{p['glane_s']:.1f} |"
            )
    peak_by_threads = {p["threads"]: p["ginstr_s"] for p in peaks if p.get("loop") == "mul+add"}
    lines += [
        "",
        "### Stages: min / median ms per call",
        "",
        f"{args.rounds} runs of {calls_per_run(args.reps, args.rounds)} calls per row (after an "
        "untimed one); min over all calls / "
        "median of the runs' medians. "
        "Forward stages from the forward's own profile; backward is the whole backward call "
        "(blend backward plus the chain to the 3D parameters). CPU: the calls' CPU time "
        "summed over the threads.",
        "",
        "| scene | Gaussians | intersections | threads | forward | project | sort | bin | "
        "blend | backward | backward / forward (min) | forward CPU | backward CPU |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]

    def mm(v: tuple[float, float]) -> str:
        return f"{v[0]:.1f} / {v[1]:.1f}"

    for r in runs:
        s = r["stages"]
        lines.append(
            f"| {r['scene']} | {r['n']:,} | {r['intersections']:,} | {r['threads']} | "
            f"{mm(s['forward'])} | {mm(s['project'])} | {mm(s['sort'])} | {mm(s['bin'])} | "
            f"{mm(s['blend'])} | {mm(s['backward'])} | "
            f"{s['backward'][0] / s['forward'][0]:.2f} | {mm(s['forward cpu'])} | "
            f"{mm(s['backward cpu'])} |"
        )
    lines += [
        "",
        "### Blending work against the ceiling",
        "",
        "Evaluated: pixel-splat alphas the kernels compute (8 per lane group, including lanes "
        "masked out); blended: pairs that pass every test. Rate: evaluations per second over "
        "the min blend time (forward: the blend stage; backward: the whole backward call, an "
        f"underestimate). Of peak: vector FP instructions ({FP_OPS_PER_GROUP['forward']} per "
        f"lane group forward, {FP_OPS_PER_GROUP['backward']} backward) per second against the "
        "`mul+add` peak at the same thread count.",
        "",
        "| scene | threads | pass | evaluated | blended | useful | G eval/s | of peak |",
        "|---|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in runs:
        for name, stage in (("forward", "blend"), ("backward", "backward")):
            e = r[name]
            secs = r["stages"][stage][0] / 1e3
            rate = e["evaluated"] / secs
            instr = e["evaluated"] / LANES * FP_OPS_PER_GROUP[name] / secs
            peak = peak_by_threads.get(r["threads"])
            of_peak = f"{100 * instr / (peak * 1e9):.0f}%" if peak else "-"
            lines.append(
                f"| {r['scene']} | {r['threads']} | {name} | {e['evaluated']:,} | "
                f"{e['blended']:,} | {100 * e['blended'] / max(e['evaluated'], 1):.0f}% | "
                f"{rate / 1e9:.2f} | {of_peak} |"
            )
    if compare:
        lines += [
            "",
            f"### Against a baseline build, interleaved ({args.threads} threads)",
            "",
            f"Baseline: {args.baseline_label or args.baseline}. "
            f"{args.rounds} rounds, each running the baseline `raster_timing` "
            f"and then the current one for {args.reps // 2} calls; min over all calls / "
            "median of the rounds' medians, ms. CPU: the calls' CPU time summed over the "
            "threads (Linux schedstat, which leaves out the time other work holds the cores).",
            "",
            "| scene | Gaussians | build | forward | backward | backward / forward (min) "
            "| forward CPU | backward CPU |",
            "|---|---:|---|---:|---:|---:|---:|---:|",
        ]
        for c in compare:
            for key in ("baseline", "current"):
                f, b = c[key]["forward"], c[key]["backward"]
                fc, bc = c[key]["forward cpu"], c[key]["backward cpu"]
                lines.append(
                    f"| {c['scene']} | {c['n']:,} | {key} | {mm(f)} | {mm(b)} | "
                    f"{b[0] / f[0]:.2f} | {mm(fc)} | {mm(bc)} |"
                )
    lines += ["", *targets(runs, args.threads)]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines += [
        "",
        f"Load average when the report was written: {load:.1f} on {os.cpu_count()} cores "
        "(other work shares the machine; the minima are the least disturbed calls).",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
