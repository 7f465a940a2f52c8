"""What randomised cameras and backgrounds cost a dataset: the same plants made with the
orbit on grey (the default) and with the random rig over a folder of background photos,
interleaved (the variants alternate which runs first), each run a fresh process on a fresh
folder: `plantdreamer generate --seeds` (the plants' runs in one process, as a dataset's
worker runs them) or, with ``--via dataset``, `plantdreamer dataset` (Ray's start
included; on a loaded 2-core machine Ray may time out starting).

Reported per variant: the whole command's wall time and the plants' export (run.json's
``renders`` + ``label files`` + ``export``, summed over the plants: the part the views
change), min and median over the repeats, and the ratio random / orbit.

    python benches/bench_views.py [--plants 8] [--repeats 3] [--views 24] [--points 30000]
        [--via generate|dataset]
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host import host_line
from view_photos import TRAINING, write_photos

RESULTS = Path(__file__).resolve().parent / "results"
EXPORT_PHASES = ("export", "renders", "label files")


def run(out: Path, args: argparse.Namespace, extra: list[str]) -> dict[str, float]:
    command = [
        sys.executable, "-m", "plantdreamer", args.via, "--species", "bean",
        "--seeds", f"0-{args.plants - 1}", "--guidance", "none", "--steps", "0",
        "--eval-views", str(args.views), "--points", str(args.points), "--out", str(out),
        "--quiet",
    ]  # fmt: skip
    if args.via == "dataset":
        command += ["--allow-empty-split", *extra]
    else:  # generate takes the settings as options
        command += [x for x in extra if x != "--set"]
    started, cpu = time.perf_counter(), resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run(command, capture_output=True, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode:
        raise SystemExit(f"{' '.join(command)} failed:\n{done.stdout[-2000:]}{done.stderr[-3000:]}")
    wall = time.perf_counter() - started
    cpu_s = (after.ru_utime + after.ru_stime) - (cpu.ru_utime + cpu.ru_stime)
    export = 0.0
    for record in sorted(out.glob("plants/*/run.json")) + sorted(out.glob("*/run.json")):
        timings = json.loads(record.read_text())["timings_s"]
        export += sum(timings.get(k, 0.0) for k in EXPORT_PHASES)
    return {"wall": wall, "cpu": cpu_s, "export": export}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--views", type=int, default=24)
    parser.add_argument("--points", type=int, default=30000)
    parser.add_argument("--via", choices=("generate", "dataset"), default="generate")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        photos = write_photos(Path(tmp) / "photos", TRAINING)
        variants = {
            "orbit on grey": [],
            "random rig, photos": ["--set", "rig=random", "--set", f"background-images={photos}"]
            if args.via == "dataset"
            else ["--rig", "random", "--background-images", str(photos)],
        }
        times: dict[str, list[dict[str, float]]] = {name: [] for name in variants}
        for repeat in range(args.repeats):
            order = list(variants) if repeat % 2 == 0 else list(reversed(variants))
            for name in order:
                out = Path(tmp) / f"{name[:5]}-{repeat}"
                times[name].append(run(out, args, variants[name]))
                print(name, repeat, times[name][-1], flush=True)
    orbit, rand = (times[name] for name in variants)
    lines = [
        "## Randomised cameras and backgrounds: their cost (`benches/bench_views.py`)",
        "",
        f"Command: `{' '.join(['python benches/bench_views.py', *sys.argv[1:]])}`. "
        f"`plantdreamer {args.via} --species bean --seeds 0-{args.plants - 1} --guidance none "
        f"--steps 0 --eval-views {args.views} --points {args.points}` (render size 512 px), "
        "once as it is (the orbit on grey, with its turntable.gif) and once with the random "
        "rig over 4 photos (`rig=random`, `background-images=DIR`, `benches/view_photos.py`; "
        f"no turntable), {args.repeats} times each, interleaved (the first variant "
        "alternates), each in a fresh process and folder. Wall: the whole command; CPU: its "
        "user + system time (what other work on the machine moves least); export: the "
        "plants' `renders` + `label files` + `export` phases (run.json, wall), summed.",
        "",
        f"Host: {host_line()}.",
        "",
        "| variant | wall min / median (s) | CPU min / median (s) | export min / median (s) |",
        "|---|---|---|---|",
    ]
    for name, runs in times.items():
        cells = []
        for key in ("wall", "cpu", "export"):
            values = [r[key] for r in runs]
            cells.append(f"{min(values):.1f} / {statistics.median(values):.1f}")
        lines.append(f"| {name} | {' | '.join(cells)} |")

    def ratios(key: str) -> list[float]:  # each repeat's two runs, back to back
        return [r[key] / o[key] for o, r in zip(orbit, rand, strict=True)]

    def summary(key: str) -> str:
        each = ratios(key)
        mins = min(r[key] for r in rand) / min(o[key] for o in orbit)
        return (
            f"{key}: per repeat {', '.join(f'{x:.3f}' for x in each)} (median "
            f"{statistics.median(each):.3f}); min / min {mins:.3f}"
        )

    lines += [
        "",
        "Random / orbit, " + "; ".join(summary(k) for k in ("cpu", "wall", "export")) + ". "
        "With no training (`--steps 0`) the export is nearly all of each plant's run, so the "
        "ratio is as large here as it gets.",
        "",
    ]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "views_cost.md").write_text("\n".join(lines))
    (RESULTS / "views_cost.json").write_text(json.dumps(times, indent=2) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
