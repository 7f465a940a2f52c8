"""What the trait files add to ``generate --guidance none``: traits.json (the mesh's and
the Gaussians' figures, each view's leaf occlusion), the views' figures in the label files
and counts.csv.

An L-System bean (seed 0, 100,000 points, as ``generate --guidance none`` makes it), 60
evaluation views at the CPU's default 512 px. Two variants, run in pairs in this one
process after a warm-up run of each, ``--repeats`` pairs, the order within a pair turned
each time (a drift of the machine's speed falls on both): ``generate`` as it is, and
``generate`` with the trait hooks replaced by no-ops (no occlusion, no traits.json, no
figures in COCO, no counts.csv: the label files as before traits). Their whole wall and CPU
times, min and median, each pair's difference, and the traits' own time inside the first
(every trait function timed where the run calls it), against the rest of the run.

    python benches/bench_traits.py [--repeats 3] [--views 60] [--points 100000]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from host import host_line

RESULTS = Path(__file__).resolve().parent / "results"


class Clock:
    """Seconds spent in the wrapped functions (their own calls, not nested ones twice):
    wall-clock and the process's CPU time (all its threads), which other processes'
    load inflates less."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.cpu: dict[str, float] = defaultdict(float)
        self.depth = 0

    def wrap(self, name: str, fn):
        def timed(*args, **kwargs):
            if self.depth:
                return fn(*args, **kwargs)
            self.depth += 1
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds[name] += time.perf_counter() - t0
                self.cpu[name] += time.process_time() - c0
                self.depth -= 1

        return timed


class NullRecorder:
    def __init__(self) -> None:
        self.views: list = []

    def add(self, *args) -> None:
        return None

    def close(self) -> None:
        return None


@contextlib.contextmanager
def patched(targets: list[tuple[object, str, object]]):
    saved = [(obj, name, getattr(obj, name)) for obj, name, _ in targets]
    try:
        for obj, name, value in targets:
            setattr(obj, name, value)
        yield
    finally:
        for obj, name, value in saved:
            setattr(obj, name, value)


def hooks(clock: Clock | None):
    """The trait functions where the run calls them: timed (``clock``) or no-ops."""
    from plantdreamer.exports import figures, plant
    from plantdreamer.pipeline import export

    if clock is None:
        return [
            (export, "view_recorder", lambda *a, **k: NullRecorder()),
            (export, "run_traits", lambda *a, **k: {}),
            (export, "write_traits", lambda *a, **k: None),
            (plant, "plant_records", lambda *a, **k: {}),
            (figures, "view_fields", lambda *a, **k: {}),
            (figures, "visible_fractions", lambda *a, **k: {}),
            (plant, "write_counts", lambda *a, **k: None),
        ]
    from plantdreamer.traits.views import ViewRecorder

    figure = "label files' figures"
    return [
        (export, "view_recorder", clock.wrap("occlusion set-up", export.view_recorder)),
        (ViewRecorder, "add", clock.wrap("occlusion", ViewRecorder.add)),
        (export, "run_traits", clock.wrap("traits.json (mesh, Gaussians)", export.run_traits)),
        (export, "write_traits", clock.wrap("traits.json (mesh, Gaussians)", export.write_traits)),
        (plant, "plant_records", clock.wrap(figure, plant.plant_records)),
        (figures, "view_fields", clock.wrap(figure, figures.view_fields)),
        (figures, "visible_fractions", clock.wrap(figure, figures.visible_fractions)),
        (plant, "write_counts", clock.wrap(figure, plant.write_counts)),
    ]


def run_once(cfg, out: Path, clock: Clock | None) -> tuple[float, float]:
    """The run's wall-clock and CPU seconds."""
    from plantdreamer.pipeline import generate_plants

    with patched(hooks(clock)):
        t0, c0 = time.perf_counter(), time.process_time()
        generate_plants([cfg], out, overwrite=True, show_progress=False)
        return time.perf_counter() - t0, time.process_time() - c0


def main() -> int:
    import torch

    from plantdreamer.pipeline import GenerateConfig

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--views", type=int, default=60)
    parser.add_argument("--points", type=int, default=100_000)
    args = parser.parse_args()
    cfg = GenerateConfig.of(species="bean", seed=0, points=args.points, guidance="none",
                            eval_views=args.views)  # fmt: skip
    load_before = os.getloadavg()[0]
    walls: dict[str, list[float]] = {"with traits": [], "without": []}
    cpus: dict[str, list[float]] = {"with traits": [], "without": []}
    clocks: list[Clock] = []
    with tempfile.TemporaryDirectory() as tmp:
        for warm_up in (Clock(), None):  # imports, first calls: not counted
            run_once(cfg, Path(tmp) / "warm", warm_up)
        for k in range(args.repeats):
            clocks.append(Clock())
            variants = [("with traits", clocks[-1]), ("without", None)]
            for name, clock in variants if k % 2 == 0 else variants[::-1]:
                wall, cpu = run_once(cfg, Path(tmp) / name.replace(" ", "_"), clock)
                walls[name].append(wall)
                cpus[name].append(cpu)
    load = f"{load_before:.1f} before, {os.getloadavg()[0]:.1f} after"
    own = [sum(c.seconds.values()) for c in clocks]
    own_cpu = [sum(c.cpu.values()) for c in clocks]
    share = [t / (w - t) for t, w in zip(own, walls["with traits"], strict=True)]
    share_cpu = [t / (w - t) for t, w in zip(own_cpu, cpus["with traits"], strict=True)]
    names = sorted({k for c in clocks for k in c.seconds})
    command = "python benches/bench_traits.py"
    if (args.repeats, args.views, args.points) != (3, 60, 100_000):
        command += f" --repeats {args.repeats} --views {args.views} --points {args.points}"

    def pair(values: list[float], scale: float = 1.0, digits: int = 1) -> str:
        return f"{min(values) * scale:.{digits}f} / {statistics.median(values) * scale:.{digits}f}"

    lines = [
        "## Trait files (`benches/bench_traits.py`)\n",
        f"Command: `{command}`. `generate --guidance none` of an L-System bean (seed 0,",
        f"{args.points:,} points), {args.views} evaluation views at 512 px, CPU, "
        f"{torch.get_num_threads()} torch threads;",
        f"{args.repeats} pairs of runs in one process after a warm-up run of each, the order",
        "within a pair turned each time; seconds, min / median. *with traits* is `generate` as",
        "it is; *without* has the trait hooks as no-ops (no occlusion, traits.json, figures in",
        "COCO or counts.csv). *traits on the run's path* is the time the run spends in the",
        "trait functions, timed where it calls them (each view's leaf occlusion among them,",
        "measured as the view is added), and *share* that time against the rest of the same",
        "run (the limit: 5%), in wall-clock and in the process's CPU time (its threads",
        "together). On a shared 2-core machine (1-minute load average",
        f"{load}) the variants' totals are noisier than the shares.\n",
        f"Host: {host_line()}.\n",
        "| variant | wall | CPU |",
        "|---|---|---|",
    ]
    for name in walls:
        lines.append(f"| {name} | {pair(walls[name])} | {pair(cpus[name])} |")
    lines += ["", "| part of the traits | wall | CPU |", "|---|---|---|"]
    for name in names:
        wall = [c.seconds.get(name, 0.0) for c in clocks]
        cpu = [c.cpu.get(name, 0.0) for c in clocks]
        lines.append(f"| {name} | {pair(wall, digits=2)} | {pair(cpu, digits=2)} |")
    lines.append(
        f"| **traits on the run's path** | **{pair(own, digits=2)}** "
        f"| **{pair(own_cpu, digits=2)}** |"
    )
    lines.append(
        f"| **share of the rest of the run** | **{pair(share, 100)}%** "
        f"| **{pair(share_cpu, 100)}%** |"
    )
    # Each run against the run of the other variant next to it (the load changes slowly).
    added = {
        kind: [w / o - 1 for w, o in zip(v["with traits"], v["without"], strict=True)]
        for kind, v in (("wall", walls), ("CPU", cpus))
    }
    lines += [
        "",
        "| *with traits* against the *without* run beside it | wall | CPU |",
        "|---|---|---|",
        "| added, each pair (in run order) | "
        + " | ".join(", ".join(f"{100 * x:+.1f}%" for x in added[k]) for k in ("wall", "CPU"))
        + " |",
        f"| **added, median of the pairs** | **{100 * statistics.median(added['wall']):+.1f}%** "
        f"| **{100 * statistics.median(added['CPU']):+.1f}%** |",
    ]
    text = "\n".join(lines) + "\n"
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "traits.md").write_text(text)
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
