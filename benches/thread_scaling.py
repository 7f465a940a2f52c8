"""The rasterizer's stages against the thread count: a prebuilt `raster_timing` binary run at
each thread count on each scene, per-stage min / median, image and gradient hashes.

    python benches/thread_scaling.py OUT --binary target/release/examples/raster_timing \\
        [--threads 1,2,4,8,16] [--scenes 100000@512,100000@768,1000000@768] [--reps 5] \\
        [--rounds R] [--baseline OTHER_BINARY]

Writes OUT/scaling.json and OUT/scaling.md. Needs no cargo: the binary is built where a
toolchain is (`cargo build --release -p splat_core --example raster_timing`) and carried
to the host being measured (`scripts/gpu_checks.py scaling` runs this on a GPU host). The
scenes are `benches/raster_scene.py`'s plant, dumped into OUT/scenes. Each (scene, threads)
run makes one untimed call, then `--reps` forward and backward calls (`BACKWARD=1 HASH=1`);
the table gives each stage's min / median and its speed-up from the fewest threads (min
over min). Equal hashes in a scene's rows show the outputs bit-identical across thread
counts; the report says whether they are.

On a shared machine, `--rounds R` repeats every run R times, the thread counts (and, with
`--baseline`, the two binaries) alternating within each round, so that load changes hit
all of them alike; a stage's cell is then the min over the rounds' mins / the median of
the rounds' mins, and the 1-minute load average at each run is recorded. `--baseline`
names a second build (the one before a change): its runs interleave with the binary's and
the report adds a before/after table.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

BENCHES = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCHES))

from host import host_line  # noqa: E402

STAGES = ("forward", "project", "sort", "bin", "blend", "backward")
DEFAULT_THREADS = "1,2,4,8,16"
DEFAULT_SCENES = "100000@512,100000@768,1000000@768"
_TIME = re.compile(r"^\s*(\w+) ms: min ([\d.]+) median ([\d.]+)$", re.M)
_HASH = re.compile(r"^(image|gradients) hash ([0-9a-f]{16})$", re.M)


def parse_scenes(text: str) -> list[tuple[int, int]]:
    """'100000@512,...' -> [(Gaussians, image size), ...]."""
    scenes = []
    for item in text.split(","):
        n, _, size = item.strip().partition("@")
        scenes.append((int(n), int(size)))
    return scenes


def parse_run(stdout: str) -> dict:
    """Per-stage [min, median] ms and the hashes of one `raster_timing` run."""
    stages = {m[1]: [float(m[2]), float(m[3])] for m in _TIME.finditer(stdout)}
    missing = [s for s in STAGES if s not in stages]
    if missing:
        raise RuntimeError(f"raster_timing printed no {', '.join(missing)} time:\n{stdout}")
    hashes = {m[1]: m[2] for m in _HASH.finditer(stdout)}
    return {"stages_ms": {s: stages[s] for s in STAGES}, "hashes": hashes}


def scene_file(folder: Path, n: int, size: int) -> Path:
    from raster_scene import dump

    path = folder / f"plant_{n}_{size}.bin"
    if not path.exists():
        folder.mkdir(parents=True, exist_ok=True)
        dump(str(path), n, size)
    return path


def measure(binary: Path, scene: Path, threads: int, reps: int) -> dict:
    env = {"BACKWARD": "1", "HASH": "1"}
    cmd = [str(binary), str(scene), str(threads), str(reps)]
    load = os.getloadavg()[0]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env={**os.environ, **env})
    return {**parse_run(out.stdout), "load": [load]}


def merge(rounds: list[dict]) -> dict:
    """One run from the same run repeated: per stage, the min of the rounds' mins and the
    median of the rounds' mins; the hashes if every round gave the same, else "differ"."""
    stages = {
        s: [min(r["stages_ms"][s][0] for r in rounds), median(r["stages_ms"][s][0] for r in rounds)]
        for s in STAGES
    }
    hashes = rounds[0]["hashes"]
    if any(r["hashes"] != hashes for r in rounds):
        hashes = {k: "differ" for k in hashes}
    return {"stages_ms": stages, "hashes": hashes, "load": [x for r in rounds for x in r["load"]]}


def median(values) -> float:
    v = sorted(values)
    return v[len(v) // 2] if len(v) % 2 else 0.5 * (v[len(v) // 2 - 1] + v[len(v) // 2])


def table(runs: list[dict]) -> str:
    lines = [
        "| scene | threads | " + " | ".join(f"{s} ms" for s in STAGES) + " | hashes |",
        "|---|---:|" + "---:|" * len(STAGES) + "---|",
    ]
    first: dict[str, dict] = {}
    for r in runs:
        base = first.setdefault(r["scene"], r)
        cells = []
        for s in STAGES:
            lo, med = r["stages_ms"][s]
            speedup = base["stages_ms"][s][0] / lo if lo > 0 else float("nan")
            cells.append(f"{lo:.2f} / {med:.2f} ({speedup:.1f}x)")
        h = r["hashes"]
        lines.append(
            f"| {r['scene']} | {r['threads']} | "
            + " | ".join(cells)
            + f" | {h.get('image', '?')} / {h.get('gradients', '?')} |"
        )
    return "\n".join(lines)


def before_after(before: list[dict], after: list[dict]) -> str:
    """Each stage at each thread count, the baseline's min against the binary's."""
    lines = [
        "| scene | stage | threads | before: min / median ms | after | after / before (min) |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for b, a in zip(before, after, strict=True):
        for s in STAGES:
            (b_lo, b_med), (a_lo, a_med) = b["stages_ms"][s], a["stages_ms"][s]
            lines.append(
                f"| {a['scene']} | {s} | {a['threads']} | {b_lo:.2f} / {b_med:.2f} | "
                f"{a_lo:.2f} / {a_med:.2f} | {a_lo / b_lo:.2f} |"
            )
    return "\n".join(lines)


def identical_across_threads(runs: list[dict]) -> bool:
    by_scene: dict[str, set] = {}
    for r in runs:
        by_scene.setdefault(r["scene"], set()).add(tuple(sorted(r["hashes"].items())))
    return all(
        len(v) == 1 and "differ" not in dict(next(iter(v))).values() for v in by_scene.values()
    )


def run(
    out: Path,
    binary: Path,
    threads: list[int],
    scenes: list[tuple[int, int]],
    reps: int,
    rounds: int = 1,
    baseline: Path | None = None,
) -> dict:
    binaries = {"after": binary, **({"before": baseline} if baseline is not None else {})}
    for b in binaries.values():
        if not b.is_file():
            raise SystemExit(
                f"error: no raster_timing binary at {b} (build it with `cargo build --release "
                "-p splat_core --example raster_timing` and pass --binary)"
            )
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    runs: dict[str, list[dict]] = {label: [] for label in binaries}
    for n, size in scenes:
        path = scene_file(out / "scenes", n, size)
        samples: dict[tuple[str, int], list[dict]] = {}
        for rnd in range(rounds):
            order = list(binaries.items())
            if rnd % 2:  # who goes first alternates too
                order.reverse()
            for t in threads:
                for label, b in order:
                    r = measure(b, path, t, reps)
                    samples.setdefault((label, t), []).append(r)
                    print(f"{n} @ {size}, {t} threads, {label}: {r['stages_ms']}", flush=True)
        for label in binaries:
            for t in threads:
                merged = merge(samples[(label, t)])
                runs[label].append(
                    {"scene": f"{n:,} @ {size}", "n": n, "size": size, "threads": t, **merged}
                )
    report = {
        "host": host_line(),
        "binary": str(binary),
        "baseline": None if baseline is None else str(baseline),
        "reps": reps,
        "rounds": rounds,
        "runs": runs["after"],
        "baseline_runs": runs.get("before"),
        "identical_across_threads": identical_across_threads(runs["after"]),
        "wall_s": time.perf_counter() - t0,
    }
    (out / "scaling.json").write_text(json.dumps(report, indent=2))
    loads = [x for r in runs["after"] for x in r["load"]]
    md = [
        f"Rasterizer stages against threads on {report['host']}; `{binary.name}`, "
        f"`BACKWARD=1 HASH=1`, {reps} calls per run after one untimed call. Each cell: "
        "min / median ms (speed-up of the min over the first row of the scene).",
    ]
    if rounds > 1:
        md.append(
            f"{rounds} rounds, thread counts{' and binaries' if baseline else ''} alternating "
            "in each; min over the rounds' mins / median of the rounds' mins; 1-minute load "
            f"average at the runs: {min(loads):.1f} to {max(loads):.1f}."
        )
    md += [
        "",
        table(runs["after"]),
        "",
        "Images and gradients bit-identical across thread counts: "
        f"{'yes' if report['identical_across_threads'] else 'NO'}. "
        f"Wall time of the whole run: {report['wall_s']:.0f} s.",
    ]
    if baseline is not None:
        same = all(
            b["hashes"] == a["hashes"] for b, a in zip(runs["before"], runs["after"], strict=True)
        )
        md += [
            "",
            f"Against `{baseline}` (before), interleaved:",
            "",
            before_after(runs["before"], runs["after"]),
            "",
            f"Hashes the same as the baseline's: {'yes' if same else 'NO'}.",
        ]
    (out / "scaling.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return report


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--binary", type=Path, required=True, help="a raster_timing release build")
    p.add_argument("--threads", default=DEFAULT_THREADS, help=f"default {DEFAULT_THREADS}")
    p.add_argument("--scenes", default=DEFAULT_SCENES, help=f"N@SIZE,... default {DEFAULT_SCENES}")
    p.add_argument("--reps", type=int, default=5, help="timed calls per run")
    p.add_argument("--rounds", type=int, default=1, help="repeat every run, interleaved")
    p.add_argument("--baseline", type=Path, help="a second raster_timing build to interleave")


def run_from_args(out: Path, args: argparse.Namespace) -> dict:
    threads = [int(t) for t in args.threads.split(",")]
    scenes = parse_scenes(args.scenes)
    return run(out, args.binary, threads, scenes, args.reps, args.rounds, args.baseline)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", type=Path, help="folder for scaling.json, scaling.md and the scenes")
    add_arguments(p)
    args = p.parse_args(argv)
    report = run_from_args(args.out, args)
    return 0 if report["identical_across_threads"] else 1


if __name__ == "__main__":
    sys.exit(main())
