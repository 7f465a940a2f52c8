"""Where a training step's time goes on the CPU, with the tiny random-weight networks.

Runs the real `generate` loop (L-System bean, SDS with the tiny models) and attributes the
whole step: render (and the native forward inside it), depth wait, guidance (and its
networks), backward (torch's part), rasterizer backward (and the native backward inside
it), gradient check, density statistics, Adam, densify/cull when due, and the rest (the
mean step less every phase: time in no phase). After the loop it times, interleaved, the
native forward alone on the final scene with the last step's arguments (the same scene,
size and threads, as `raster_timing` would) and the model's whole render of that camera,
so the render's cost beyond the kernels can be read without the networks beside it.

    python benches/bench_step_profile.py                       # this tree, one run
    python benches/bench_step_profile.py --trees BEFORE .      # alternate two trees

With `--trees`, each round runs one process per tree in turn (PYTHONPATH = TREE/python,
each tree with its own native module), and the tables give min / median over rounds.
Writes benches/results/step_phases.md (and .json) unless `--md` says otherwise.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

BENCHES = Path(__file__).resolve().parent
RESULTS = BENCHES / "results"
COMMAND = "python benches/bench_step_profile.py"
REST = "rest (in no phase)"
# Rows in report order; "of which" rows are parts of the row above them, not added twice.
ROWS = (
    "render",
    "  of which native forward",
    "depth (wait)",
    "guidance",
    "  of which networks",
    "backward (torch)",
    "rasterizer backward",
    "  of which native backward",
    "gradient check",
    "density statistics",
    "adam",
    "optimizer other",
    "densify + cull",
    REST,
)
PARTS = {"  of which native forward", "  of which networks", "  of which native backward"}


class Clock:
    """Seconds per named call, with each call's start, so steps can be cut out later."""

    def __init__(self) -> None:
        self.events: list[tuple[float, str, float]] = []

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.events.append((t0, name, time.perf_counter() - t0))

    def wrap(self, name: str, fn: Callable) -> Callable:
        def timed(*args: Any, **kwargs: Any) -> Any:
            with self(name):
                return fn(*args, **kwargs)

        return timed

    def between(self, start: float, end: float) -> dict[str, float]:
        """Seconds per name of the calls that began in [start, end)."""
        totals: dict[str, float] = defaultdict(float)
        for t0, name, seconds in self.events:
            if start <= t0 < end:
                totals[name] += seconds
        return totals


class TimedCore:
    """`plantdreamer._core` with the rasterizer's two native calls timed; keeps the last
    forward's arguments so the same call can be repeated alone after the loop."""

    def __init__(self, core: Any, clock: Clock) -> None:
        self._core, self._clock = core, clock
        self.last_forward: tuple[tuple, dict] | None = None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._core, name)

    def rasterize_forward_many(self, *args: Any, **kwargs: Any) -> Any:
        if kwargs.get("render_color", True) and not kwargs.get("render_depth", False):
            self.last_forward = (args, kwargs)  # an RGB training render, not a depth map
            with self._clock("native forward"):
                return self._core.rasterize_forward_many(*args, **kwargs)
        return self._core.rasterize_forward_many(*args, **kwargs)

    def rasterize_backward_many(self, *args: Any, **kwargs: Any) -> Any:
        with self._clock("native backward"):
            return self._core.rasterize_backward_many(*args, **kwargs)


def phase_clock(clock: Clock) -> Any:
    """A trainer observer that puts the loop's phases on ``clock`` (``loop:<phase>``) and
    keeps the plant's model and sampler, for ``alone`` after the loop."""
    from plantdreamer.pipeline.observer import TrainerObserver

    class PhaseClock(TrainerObserver):
        def __init__(self) -> None:
            self.held: dict[str, Any] = {}

        def phase_end(self, phase: str, seconds: float) -> None:
            clock.events.append((time.perf_counter() - seconds, "loop:" + phase, seconds))

        def step_end(self, step: int, plants: Any, loss: float | None) -> None:
            self.held = {"model": plants[0].state.model, "sampler": plants[0].state.sampler}

    return PhaseClock()


def instrument(guidance: Any, clock: Clock) -> TimedCore:
    """Times the parts inside the loop's phases (bench only; the phases themselves come
    from the trainer's observer, ``phase_clock``)."""
    import torch

    from plantdreamer import rasterizer
    from plantdreamer.pipeline.model import density
    from plantdreamer.pipeline.step import update

    for part in ("text_embedding", "noise_prediction", "encode"):
        setattr(guidance, part, clock.wrap("networks", getattr(guidance, part)))
    core = TimedCore(rasterizer._core, clock)
    rasterizer._core = core  # type: ignore[assignment]
    fn = rasterizer._RasterizeManyFunction
    fn.backward = staticmethod(clock.wrap("rasterizer backward", fn.backward))
    update.check_finite_gradients = clock.wrap("gradient check", update.check_finite_gradients)
    ctl = density.DensityControl
    ctl.after_backward = clock.wrap("density statistics", ctl.after_backward)  # type: ignore[method-assign]
    torch.optim.Adam.step = clock.wrap("adam", torch.optim.Adam.step)  # type: ignore[method-assign]
    return core


def per_step(totals: dict[str, float], steps: int, mean_step_s: float) -> dict[str, float]:
    """ms per step of every row; the rest is the mean step less every phase."""
    g = defaultdict(float, totals)
    raster_bwd = g["rasterizer backward"]
    rows = {
        "render": g["loop:raster.forward"],
        "  of which native forward": g["native forward"],
        "depth (wait)": g["loop:depth"],
        "guidance": g["loop:guidance.launch"] + g["loop:guidance.wait"],
        "  of which networks": g["networks"],
        "backward (torch)": g["loop:guidance.backward"] + g["loop:raster.backward"] - raster_bwd,
        "rasterizer backward": raster_bwd,
        "  of which native backward": g["native backward"],
        "gradient check": g["gradient check"],
        "density statistics": g["density statistics"],
        "adam": g["adam"],
        "optimizer other": g["loop:optimizer"]
        - g["gradient check"]
        - g["density statistics"]
        - g["adam"],
        "densify + cull": g["loop:densify"] + g["loop:cull"],
    }
    ms = {k: 1000 * v / steps for k, v in rows.items()}
    ms[REST] = 1000 * mean_step_s - sum(v for k, v in ms.items() if k not in PARTS)
    return ms


def alone(core: TimedCore, model: Any, camera: Any, background: float, reps: int) -> dict:
    """The native forward alone and the model's render of the same camera, interleaved."""
    assert core.last_forward is not None
    args, kwargs = core.last_forward
    native, render, beyond = [], [], []
    for _ in range(reps + 1):
        t0 = time.perf_counter()
        core._core.rasterize_forward_many(*args, **kwargs)
        t1 = time.perf_counter()
        model.render([camera], background)  # its native call is timed by `core`
        t2 = time.perf_counter()
        native.append(t1 - t0)
        render.append(t2 - t1)
        beyond.append(t2 - t1 - core._clock.events[-1][2])
    # The first of each is a warm-up.
    return {
        "native_forward_ms": [1000 * x for x in native[1:]],
        "model_render_ms": [1000 * x for x in render[1:]],
        "beyond_native_ms": [1000 * x for x in beyond[1:]],
        "gaussians": len(model),
    }


def child(args: argparse.Namespace) -> dict[str, Any]:
    import torch

    sys.path.insert(0, str(BENCHES))
    from bench_gpu import build_guidance

    from plantdreamer.pipeline import GenerateConfig, generate_plants

    guidance = build_guidance(True, "cpu", args.sds)
    clock = Clock()
    core = instrument(guidance, clock)
    cfg = GenerateConfig.of(
        species="bean",
        seed=0,
        points=args.points,
        steps=args.warmup + args.steps + 1,
        resolution=args.render,
        sds_resolution=args.sds,
        eval_views=1,
        turntable_frames=1,
        checkpoint_every=10**9,
    )
    stamps: list[float] = []
    phases = phase_clock(clock)
    with tempfile.TemporaryDirectory() as tmp:
        generate_plants(
            [cfg],
            tmp,
            guidance=guidance,
            show_progress=False,
            observers=[phases],
            on_step=lambda step: stamps.append(time.perf_counter()),
        )
        stamps = stamps[args.warmup :]
        step_s = [b - a for a, b in itertools.pairwise(stamps)]
        # Phases of the steps between the first and the last timed stamp (not the
        # evaluation renders and export after the loop).
        totals = clock.between(stamps[0], stamps[-1])
        camera = phases.held["sampler"].peek()  # the next camera: the same scene and size
        reps = alone(core, phases.held["model"], camera, cfg.train.background, args.alone)
    return {
        "per_step_ms": per_step(totals, len(step_s), statistics.fmean(step_s)),
        "step_ms_median": 1000 * statistics.median(step_s),
        "step_ms_mean": 1000 * statistics.fmean(step_s),
        "alone": reps,
        "torch_threads": torch.get_num_threads(),
        "load": os.getloadavg()[0],
    }


def cell(values: list[float]) -> str:
    return f"{min(values):.2f} / {statistics.median(values):.2f}"


def report(runs: dict[str, list[dict[str, Any]]], argv: list[str], args: argparse.Namespace) -> str:
    sys.path.insert(0, str(BENCHES))
    from host import host_line

    names = list(runs)
    head = " | ".join(names)
    lines = [
        "## The step's phases on the CPU (`benches/bench_step_profile.py`)\n",
        f"Command: `{' '.join([COMMAND, *argv])}`. Host: {host_line()}. The real `generate` loop",
        f"(L-System bean, seed 0, {args.points:,} points, SH degree 0, render {args.render},",
        f"SDS {args.sds} with the tiny random-weight networks, depth ahead), {args.steps} timed",
        f"steps after {args.warmup} untimed; {args.rounds} round(s), one process per tree per",
        "round, trees alternating. Cells: ms per step, min / median over rounds of each run's",
        "mean; the rest is the mean step less every phase; indented rows are parts of the row",
        "above them. 1-minute load average at the start of the runs: "
        + ", ".join(f"{r['load']:.1f}" for rs in runs.values() for r in rs)
        + ".",
        "",
        f"| phase, ms per step | {head} |",
        "|---|" + "---:|" * len(names),
    ]
    for row in ROWS:
        cells = [cell([r["per_step_ms"][row] for r in runs[n]]) for n in names]
        lines.append(f"| {row} | " + " | ".join(cells) + " |")
    for key, label in (("step_ms_mean", "step (mean wall)"), ("step_ms_median", "step (median)")):
        cells = [cell([r[key] for r in runs[n]]) for n in names]
        lines.append(f"| **{label}** | " + " | ".join(cells) + " |")
    lines += [
        "",
        f"After the loop, the last step's native forward alone and the model's render of the "
        f"same camera (with autograd, as in the step), interleaved, {args.alone} calls each "
        "per run; min / median over all calls of all rounds, ms:",
        "",
        f"| call | {head} |",
        "|---|" + "---:|" * len(names),
    ]
    series = (
        ("native_forward_ms", "native forward alone"),
        ("model_render_ms", "model render"),
        ("beyond_native_ms", "model render less its own native call"),
    )
    for key, label in series:
        cells = [cell([x for r in runs[n] for x in r["alone"][key]]) for n in names]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    # The kernels' best call plus the Python side's best: two noisy calls' ratio would not be.
    ratios = []
    for n in names:
        native = min(x for r in runs[n] for x in r["alone"]["native_forward_ms"])
        beyond = min(x for r in runs[n] for x in r["alone"]["beyond_native_ms"])
        ratios.append(f"{(native + beyond) / native:.2f}")
    lines.append(
        "| (native forward + render less native) / native forward, best calls | "
        + " | ".join(ratios)
        + " |"
    )
    gaussians = {r["alone"]["gaussians"] for rs in runs.values() for r in rs}
    lines += ["", f"Gaussians at the end of the loop: {', '.join(map(str, sorted(gaussians)))}."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=12)
    p.add_argument("--warmup", type=int, default=2)
    p.add_argument("--render", type=int, default=512)
    p.add_argument("--sds", type=int, default=128)
    p.add_argument("--points", type=int, default=100_000)
    p.add_argument("--alone", type=int, default=10, help="calls of the native-alone pair")
    p.add_argument("--rounds", type=int, default=1)
    p.add_argument("--trees", nargs="+", type=Path, help="source trees to alternate")
    p.add_argument("--md", type=Path, default=RESULTS / "step_phases.md")
    p.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.steps < 2:
        p.error("--steps must be at least 2 (step times are differences)")
    if args.child is not None:
        args.child.write_text(json.dumps(child(args)))
        return 0
    trees = args.trees or [BENCHES.parent]
    labels = [str(t) if args.trees else "this tree" for t in trees]
    runs: dict[str, list[dict[str, Any]]] = {label: [] for label in labels}
    forwarded = _without_option(argv, "--trees", len(trees))
    forwarded = _without_option(forwarded, "--md", 1)
    with tempfile.TemporaryDirectory() as tmp:
        for rnd in range(args.rounds):
            for label, tree in zip(labels, trees, strict=True):
                out = Path(tmp) / f"{rnd}-{labels.index(label)}.json"
                env = {**os.environ, "PYTHONPATH": str(tree.resolve() / "python")}
                cmd = [sys.executable, __file__, *forwarded, "--child", str(out)]
                subprocess.run(cmd, env=env, check=True)
                runs[label].append(json.loads(out.read_text()))
                print(f"round {rnd + 1}, {label}: step {runs[label][-1]['step_ms_median']:.1f} ms")
    text = report(runs, argv, args)
    print(text)
    args.md.parent.mkdir(parents=True, exist_ok=True)
    args.md.write_text(text)
    args.md.with_suffix(".json").write_text(json.dumps(runs, indent=1))
    return 0


def _without_option(argv: list[str], name: str, values: int) -> list[str]:
    """argv less ``name`` and the ``values`` arguments after it."""
    out, skip = [], 0
    for a in argv:
        if skip:
            skip -= 1
        elif a == name:
            skip = values
        elif a.startswith(name + "="):
            continue
        else:
            out.append(a)
    return out


if __name__ == "__main__":
    sys.exit(main())
