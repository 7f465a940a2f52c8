"""The real `generate` loop with SDS, per phase: full-size networks on CUDA, tiny on the CPU.

On a CUDA machine (default there): SD 2.1-base-sized UNet, ControlNet, VAE and text encoder
with random weights (`guidance/full_size.py`, nothing downloaded), UNet/ControlNet/text
encoder in fp16 and the VAE in fp32 (the defaults), renders at 768 and SDS at 512. On a
CPU-only machine it runs the same loop with the tiny models at 512 (`--tiny`).

    python benches/bench_gpu.py --steps 200                 # on the GPU machine
    python benches/bench_gpu.py --steps 20 --tiny           # CPU, tiny models
    python benches/bench_gpu.py --steps 20 --tiny --compare-depth 5

Per step it reports render (rasterizer forward), depth (ControlNet conditioning: with depth
ahead, the wait for the worker), transfer (host -> device copies), text, unet+controlnet,
vae encode, guidance other (the guidance call less its timed parts: control image, noise,
loss, statistics), rasterizer backward, vae backward (the rest of `loss.backward()`),
optimiser, densify and cull when they ran, and the rest: the mean step less every phase
(the camera draw, the gradient checks, density statistics, logging: time in no phase).
Phases and steps are those between the first and the last step's end (steps 2..n; the
first also waits for the first depth map and, on CUDA, the graph captures);
the wall time per step; on CUDA the peak GPU memory. The report names the host's CPU
model and usable cores beside the GPU (CPU phases move with the host). `--profile N` adds
the N functions of most own time per step (cProfile over the timed steps). Each timed call is bracketed by
`torch.cuda.synchronize()` on CUDA, so phases do not hide each other's GPU time. The
phase rows are means over the timed steps, after ``--warmup`` untimed steps (on CUDA, the
graph captures and the first prompt encodes); the step row is the median. The
projection is the median step wall time x 3600; on CUDA it comes from a second run of
the same steps without the per-phase syncs (preparation, evaluation renders and
export not included). `--compare-depth R` interleaves R rounds of depth in line and depth
ahead and reports min and median of each (for a shared machine).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import itertools
import json
import pstats
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch

BENCHES = Path(__file__).resolve().parent
RESULTS = BENCHES / "results"
sys.path.insert(0, str(BENCHES))

from host import host_line  # noqa: E402

GOAL_3600_S = 300.0  # the target: 3600 steps in 5 minutes on one H100
NETWORK_PHASES = ("text", "unet+controlnet", "vae encode", "vae backward")
# Timed inside the guidance call; what the call spends beyond them is "guidance other".
GUIDANCE_PARTS = ("text", "unet+controlnet", "vae encode", "transfer")
# The loop's own timers (pipeline/run.py) reported as phases; "guidance" and "backward" are
# split into the parts above.
LOOP_PHASES = ("raster.forward", "depth", "optimizer", "densify", "cull")
REST = "rest (in no phase)"
LOOP_PREFIX = "loop:"


class PhaseClock:
    """Seconds per phase, summed; synchronises CUDA around each timed call."""

    def __init__(self, cuda: bool) -> None:
        self.cuda = cuda
        self.enabled = True  # off: no syncs, no timing (the plain step time)
        self.totals: dict[str, float] = defaultdict(float)
        # (start, phase, seconds) of every timed call, the loop's own phases included, so
        # that the phases of the steps between two step stamps can be summed.
        self.events: list[tuple[float, str, float]] = []

    @contextmanager
    def __call__(self, name: str):
        if not self.enabled:
            yield
            return
        if self.cuda:
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        try:
            yield
        finally:
            if self.cuda:
                torch.cuda.synchronize()
            seconds = time.perf_counter() - t0
            self.totals[name] += seconds
            self.events.append((t0, name, seconds))

    def since(self, start: float) -> dict[str, float]:
        """Seconds per phase of the calls that began at or after ``start``."""
        totals: dict[str, float] = defaultdict(float)
        for t0, name, seconds in self.events:
            if t0 >= start:
                totals[name] += seconds
        return totals

    def wrap(self, name: str, fn: Callable) -> Callable:
        def timed(*args: Any, **kwargs: Any) -> Any:
            with self(name):
                return fn(*args, **kwargs)

        return timed


def record_loop_phases(clock: PhaseClock) -> None:
    """Adds every phase the generate loop times itself (render, depth, guidance, backward,
    optimizer, densify, ...) to the clock's events, with its start time."""
    from plantdreamer.pipeline import progress as loop

    timed_phase = loop.PhaseTimer.__call__

    @contextmanager
    def recorded(self: Any, name: str):
        t0 = time.perf_counter()
        with timed_phase(self, name):
            yield
        clock.events.append((t0, LOOP_PREFIX + name, time.perf_counter() - t0))

    loop.PhaseTimer.__call__ = recorded  # type: ignore[method-assign]


def instrument(guidance: Any, clock: PhaseClock) -> None:
    """Times the guidance's parts and the rasterizer's backward (bench only)."""
    from plantdreamer import rasterizer
    from plantdreamer.guidance import sds

    record_loop_phases(clock)
    guidance.text_embedding = clock.wrap("text", guidance.text_embedding)
    guidance.noise_prediction = clock.wrap("unet+controlnet", guidance.noise_prediction)
    guidance.encode = clock.wrap("vae encode", guidance.encode)
    sds.to_device = clock.wrap("transfer", sds.to_device)
    fn = rasterizer._RasterizeManyFunction
    fn.backward = staticmethod(clock.wrap("raster backward", fn.backward))


def build_guidance(tiny: bool, device: str, sds_resolution: int) -> Any:
    from plantdreamer.guidance import StableDiffusionDepthGuidance
    from plantdreamer.guidance.full_size import full_size_models
    from plantdreamer.guidance.tiny import tiny_models

    parts = tiny_models() if tiny else full_size_models(device=device)
    return StableDiffusionDepthGuidance(
        species="bean", components=parts, resolution=sds_resolution, device=device, seed=0
    )


def top_functions(profiler: cProfile.Profile, steps: int, n: int) -> str:
    """The n functions of most own time, in ms per step (cProfile's table, rescaled)."""
    stream = io.StringIO()
    stats = pstats.Stats(profiler, stream=stream)
    rows = sorted(stats.stats.items(), key=lambda kv: -kv[1][2])[:n]  # type: ignore[attr-defined]
    lines = [
        "| function | calls / step | own ms / step | with callees ms / step |",
        "|---|---|---|---|",
    ]
    for (path, line, name), (_, calls, own, cumulative, _) in rows:
        where = f"{Path(path).name}:{line}({name})" if line else name
        lines.append(
            f"| `{where}` | {calls / max(steps, 1):.1f} | {1000 * own / max(steps, 1):.2f} | "
            f"{1000 * cumulative / max(steps, 1):.2f} |"
        )
    return "\n".join(lines)


def run_once(
    args: argparse.Namespace,
    guidance: Any,
    clock: PhaseClock,
    depth_ahead: bool,
    profile: int = 0,
) -> dict[str, Any]:
    from plantdreamer.pipeline import GenerateConfig, StepOptions, generate_plants

    cuda = guidance.device.type == "cuda"
    clock.totals.clear()
    clock.events.clear()
    cfg = GenerateConfig.of(
        species="bean",
        seed=0,
        points=args.points,
        steps=args.steps,
        resolution=args.render,
        sds_resolution=args.sds,
        eval_views=1,
        turntable_frames=1,
        checkpoint_every=10**9,
    )
    stamps: list[float] = []
    if cuda:
        torch.cuda.reset_peak_memory_stats(guidance.device)
    profiler = cProfile.Profile() if profile else None
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        if profiler is not None:
            profiler.enable()
        generate_plants(
            [cfg],
            tmp,
            guidance=guidance,
            show_progress=False,
            on_step=lambda step: stamps.append(time.perf_counter()),
            options=StepOptions(depth_ahead=depth_ahead),
        )
        if profiler is not None:
            profiler.disable()
        wall = time.perf_counter() - t0
    steps = len(stamps)
    step_s = [b - a for a, b in itertools.pairwise(stamps)]
    # Phases of steps 2..n, the steps between the first and the last stamp (the first
    # step also waits for the first depth map and, on CUDA, graph captures).
    timed = clock.since(stamps[0]) if stamps else {}
    loop_phase = {
        k.removeprefix(LOOP_PREFIX): v for k, v in timed.items() if k.startswith(LOOP_PREFIX)
    }
    parts = {k: v for k, v in timed.items() if not k.startswith(LOOP_PREFIX)}
    phases = {k: v for k, v in parts.items() if k != "raster backward"}
    guidance_s = loop_phase.get("guidance.launch", 0.0) + loop_phase.get("guidance.wait", 0.0)
    backward = loop_phase.get("guidance.backward", 0.0) + loop_phase.get("raster.backward", 0.0)
    phases["guidance other"] = guidance_s - sum(parts.get(p, 0.0) for p in GUIDANCE_PARTS)
    phases["raster backward"] = parts.get("raster backward", 0.0)
    phases["vae backward"] = backward - phases["raster backward"]
    for name in LOOP_PHASES:
        if name in loop_phase or name in ("raster.forward", "depth", "optimizer"):
            phases[name] = loop_phase.get(name, 0.0)
    intervals = max(len(step_s), 1)
    per_step_ms = {k: 1000 * v / intervals for k, v in phases.items()}
    mean_step_ms = 1000 * statistics.fmean(step_s) if step_s else float("nan")
    per_step_ms[REST] = mean_step_ms - sum(per_step_ms.values())
    median_step = statistics.median(step_s) if step_s else float("nan")
    network_ms = sum(per_step_ms.get(p, 0.0) for p in NETWORK_PHASES)
    return {
        "device": str(guidance.device),
        "device_name": torch.cuda.get_device_name(guidance.device) if cuda else "cpu",
        "host": host_line(),
        "torch": torch.__version__,
        "profile": None if profiler is None else top_functions(profiler, steps, profile),
        "models": "tiny" if args.tiny else "full size (random weights)",
        "dtypes": {
            "unet": str(guidance.dtype),
            "controlnet": str(guidance.dtype),
            "text_encoder": str(guidance.dtype),
            "vae": str(guidance.vae_dtype),
        },
        "render": args.render,
        "sds": args.sds,
        "points": args.points,
        "steps": steps,
        "depth_ahead": depth_ahead,
        "per_step_ms": per_step_ms,
        "step_ms_mean": mean_step_ms,
        "step_ms_median": 1000 * median_step,
        "step_ms_min": 1000 * min(step_s) if step_s else float("nan"),
        "non_network_ms": 1000 * median_step - network_ms,
        "peak_gpu_gib": torch.cuda.max_memory_allocated(guidance.device) / 2**30 if cuda else None,
        "projected_3600_steps_s": 3600 * median_step,
        "wall_s": wall,
    }


def table(report: dict[str, Any]) -> str:
    rows = [f"| {k} | {v:.1f} |" for k, v in report["per_step_ms"].items()]
    lines = [
        f"{report['models']} on {report['device_name']} (host: {report['host']}; torch "
        f"{report['torch']}), render {report['render']}, SDS {report['sds']}, "
        f"{report['points']} points, {report['steps']} steps, depth ahead: {report['depth_ahead']}",
        "",
        "| phase | ms / step |",
        "|---|---|",
        *rows,
        f"| **step (mean wall)** | {report['step_ms_mean']:.1f} |",
        f"| **step (median wall)** | {report['step_ms_median']:.1f} |",
        f"| non-network part (step - text - UNet/ControlNet - VAE) | "
        f"{report['non_network_ms']:.1f} |",
    ]
    if "plain_step_ms_median" in report:
        lines.append(
            f"| **step without the per-phase syncs (median / min wall)** | "
            f"{report['plain_step_ms_median']:.1f} / {report['plain_step_ms_min']:.1f} |"
        )
    lines += [
        "",
        f"Projected 3600 steps: {report['projected_3600_steps_s']:.0f} s "
        f"(goal {GOAL_3600_S:.0f} s).",
    ]
    if report["peak_gpu_gib"] is not None:
        lines.append(f"Peak GPU memory: {report['peak_gpu_gib']:.2f} GiB.")
    if report.get("profile"):
        lines += ["", "Functions of most own time (cProfile, timed steps):", "", report["profile"]]
    return "\n".join(lines)


def compare_depth(args: argparse.Namespace, guidance: Any, clock: PhaseClock) -> str:
    """Depth in line vs ahead, interleaved rounds; min and median of the median step."""
    runs: dict[bool, list[dict[str, Any]]] = {False: [], True: []}
    for _ in range(args.compare_depth):
        for ahead in (False, True):
            runs[ahead].append(run_once(args, guidance, clock, ahead))
    phases = list(runs[True][0]["per_step_ms"])
    lines = [
        f"{args.compare_depth} interleaved rounds of {args.steps} steps each; "
        "ms per step, min / median over rounds.",
        "",
        "| phase | depth in line (before) | depth ahead (after) |",
        "|---|---|---|",
    ]

    def cell(values: list[float]) -> str:
        return f"{min(values):.1f} / {statistics.median(values):.1f}"

    for phase in phases:
        lines.append(
            f"| {phase} | "
            + " | ".join(
                cell([r["per_step_ms"].get(phase, 0.0) for r in runs[a]]) for a in (False, True)
            )
            + " |"
        )
    for key, label in (
        ("step_ms_mean", "step (mean wall)"),
        ("step_ms_median", "step (median wall)"),
        ("non_network_ms", "non-network part"),
    ):
        lines.append(
            f"| **{label}** | "
            + " | ".join(cell([r[key] for r in runs[a]]) for a in (False, True))
            + " |"
        )
    return "\n".join(lines)


def section(args: argparse.Namespace, guidance: Any, text: str, argv: list[str]) -> str:
    command = " ".join(["python benches/bench_gpu.py", *argv])
    lines = [
        f"## SDS loop per phase{' on CUDA' if guidance.device.type == 'cuda' else ''} "
        "(`benches/bench_gpu.py`)\n",
        f"Command: `{command}`.\n",
        text,
        "",
        f"(L-System bean, seed 0, {args.points:,} points, render {args.render}, SDS {args.sds}, "
        f"{'tiny random-weight' if args.tiny else 'full-size random-weight'} models, "
        f"{guidance.device.type.upper()}.) The non-network part is the median step less its "
        "text, UNet/ControlNet and VAE phases.",
        "",
    ]
    if guidance.device.type != "cuda":
        lines += [
            "### GPU\n",
            "The full-size figures on a CUDA GPU (fp16 UNet/ControlNet, fp32 VAE, render 768,",
            "SDS 512) are in the sections below, from `python benches/bench_gpu.py --steps 200`",
            "on a CUDA machine, which writes `benches/results/gpu_cuda.md`.\n",
        ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    cuda = torch.cuda.is_available()
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=200 if cuda else 20)
    p.add_argument("--tiny", action="store_true", default=not cuda, help="tiny models")
    p.add_argument("--device", default="cuda" if cuda else "cpu")
    p.add_argument("--render", type=int, default=768 if cuda else 512)
    p.add_argument("--sds", type=int, default=512)
    p.add_argument("--points", type=int, default=100_000)
    p.add_argument(
        "--warmup",
        type=int,
        default=5 if cuda else 0,
        help="untimed steps first (CUDA graph capture, first prompt encodes)",
    )
    p.add_argument("--compare-depth", type=int, default=0 if cuda else 3, metavar="ROUNDS")
    p.add_argument(
        "--profile", type=int, default=0, metavar="N", help="list the N costliest functions"
    )
    p.add_argument("--json", type=Path, help="also write the report as JSON here")
    p.add_argument(
        "--md", type=Path, help="markdown section (default: results/gpu.md, gpu_cuda.md)"
    )
    args = p.parse_args(argv)
    if args.steps < 2:
        p.error("--steps must be at least 2 (step times are differences)")
    if args.device.startswith("cuda") and not cuda:
        p.error("no CUDA GPU here: run without --device (tiny models on the CPU, --tiny)")

    guidance = build_guidance(args.tiny, args.device, args.sds)
    if args.md is None:
        args.md = RESULTS / ("gpu_cuda.md" if guidance.device.type == "cuda" else "gpu.md")
    clock = PhaseClock(guidance.device.type == "cuda")
    instrument(guidance, clock)
    if args.warmup:
        run_once(argparse.Namespace(**{**vars(args), "steps": args.warmup}), guidance, clock, True)
    if args.compare_depth:
        text = compare_depth(args, guidance, clock)
        report: dict[str, Any] = {"compare_depth": text}
    else:
        report = run_once(args, guidance, clock, depth_ahead=True, profile=args.profile)
        if report["device"].startswith("cuda"):
            # The per-phase syncs serialise the host and the GPU; a second run without them
            # gives the step time a user sees, and the projection.
            clock.enabled = False
            plain = run_once(args, guidance, clock, depth_ahead=True)
            report["plain_step_ms_median"] = plain["step_ms_median"]
            report["plain_step_ms_min"] = plain["step_ms_min"]
            report["projected_3600_steps_s"] = plain["projected_3600_steps_s"]
            report["peak_gpu_gib"] = max(report["peak_gpu_gib"], plain["peak_gpu_gib"])
        text = table(report)
    print(text)
    args.md.parent.mkdir(parents=True, exist_ok=True)
    args.md.write_text(section(args, guidance, text, sys.argv[1:] if argv is None else argv))
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
