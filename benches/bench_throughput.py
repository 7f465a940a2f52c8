"""Plants per hour in the steady state: B plants in one trainer (`generate --seeds`).

Each run trains one group of B L-System beans (seeds 0..B-1) through the pipeline's one entry (``generate_plants``)
and records, through its ``on_step`` hook, the wall clock and the process's CPU time at
every step end. The figures are the **steady state**, after ``--warmup`` steps (7: the
CUDA-graph captures and first prompt encodes fall in them):

* ``step_ms_median``: the median wall time between consecutive step ends after warm-up;
  ``plants_per_hour`` = 3600 s x B / (that median x 3600 steps per plant);
* ``gpu_busy``: the share of the steady window's wall time the GPU was busy: NVML's
  utilisation sampled every 50 ms (``pynvml``), else the union of the kernels' intervals
  from the torch profiler over the window; null without CUDA;
* ``device_ms_per_plant_step``: the GPU's busy time per plant-step (``gpu_busy`` x the
  window / (steps x B)), beside the host's figures: which side bounds the step;
* ``host_core_ms_per_plant_step``: process CPU time (every thread) over the steady window
  / (steps x B): what the host's cores spend per plant-step, rasterizer and Python alike
  (on the CPU the tiny networks' arithmetic is in it too);
* ``host_serial_ms_per_step``: the CPU time of the step's own thread (the loop, the
  native calls' callers, the guidance's launch and wait) per step over the same window:
  the serial part of a step, which no number of cores shortens;
* ``raster_core_ms_per_plant``: the rasterizer alone at the render size in the same run:
  one forward and backward of a plant's initial Gaussians (process CPU time), the mean
  over ``REFERENCE_RENDERS`` cameras the first plants trained on in the steady window
  (``raster_renders`` of them; ``raster_range``: the cheapest and the costliest over the
  mean);
  and ``host_to_raster``, the host's core-ms per plant-step over it: what the step adds
  around the rasterizer;
* ``phases_ms``: the step's phases (``pipeline.export.STEP_PHASES``: raster.forward, depth,
  guidance.launch, guidance.backward, guidance.wait, raster.backward, optimizer), ms per
  group step, means over every step: the sum of the plants' run.json figures (each plant
  records its share of a phase that ran for several);
* ``peak_cuda_gib``: ``torch.cuda.max_memory_allocated`` over the run (null on the CPU).

Full-size random-weight networks (SD 2.1-base sizes) on CUDA; ``--tiny`` networks on the CPU
(the default without CUDA). Runs are B x overlap x VAE precision (``--groups``,
``--overlap``, ``--vae``; B = 1 runs once, without overlap), interleaved over ``--repeats``.

    python benches/bench_throughput.py                            # CUDA: B = 1, 8, 16, 32
    python benches/bench_throughput.py --tiny --groups 1 4 --steps 12 --render 128
    python benches/bench_throughput.py --tiny --groups 4 --trace timeline.json   # one step
    python benches/bench_throughput.py --loading 8     # model loading per plant vs per worker

``--trace PATH`` profiles one steady step (the step after warm-up) of the first run with the
torch profiler (host threads; CUDA streams on CUDA) and writes it as a Chrome trace
(``scripts/plot_timeline.py`` draws it). ``--cuda-wait spin sleep`` compares the host's
wait for the device (CUDA only; ``StepOptions.sleeping_wait``), interleaved: CUDA's
default spinning wait against a blocking event that lets the thread sleep (the same bits).
``--networks stub`` runs no network (``stub_guidance.py``: a fixed, deterministic render
gradient; the depth conditioning is still made), so the host's own work per plant-step is
measured apart from the networks that a GPU would run.

``--render 768 512`` compares render sizes (each a run; the SDS size stays). ``--baseline
DIR`` makes every run with an earlier package too (``DIR/plantdreamer``: a checkout's
``python/`` with its native module, or an unpacked wheel), before this tree's in each
repeat, each run in a process of its own: a before/after in one bench, under the same load.
The baseline must have the calls this bench makes (``generate_plants``, or before it
``generate_group``, with ``options``).

``--loading N`` measures what a dataset worker pays to get each plant's guidance, for N
plants: with the models loaded for every plant (a new ``dataset.worker.ModelCache`` per
plant) and once per worker (one cache for all N, as a ``PlantWorker`` does).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import itertools
import json
import math
import os
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host import host_line

RESULTS = Path(__file__).resolve().parent / "results"
# pipeline.export.STEP_PHASES (tests/test_bench_throughput.py checks they agree).
PHASES = ("raster.forward", "depth", "guidance.launch", "guidance.backward", "guidance.wait",
          "raster.backward", "optimizer")  # fmt: skip
STEPS_PER_PLANT = 3600
NVML_PERIOD_S = 0.05


@dataclass(frozen=True)
class Variant:
    b: int
    overlap: str = "off"
    vae: str = "float32"
    cuda_wait: str = "sleep"
    render: int | None = None  # None: the run's one --render
    stub_depth: str = "on"  # --networks stub: the depth maps made ("on") or left out
    build: str = "this"  # or "baseline": the package under --baseline

    @property
    def label(self) -> str:
        parts = [str(self.b)]
        parts += ["overlap"] if self.overlap == "on" else []
        parts += [self.vae] if self.vae != "float32" else []
        parts += ["spin-wait"] if self.cuda_wait == "spin" else []
        parts += [f"r{self.render}"] if self.render is not None else []
        parts += ["no-depth"] if self.stub_depth == "off" else []
        parts += ["baseline"] if self.build == "baseline" else []
        return "-".join(parts)


# The switches a run compares side by side (each a Variant field, its default the field's):
# (field, choices, help).
SWITCHES = (
    ("cuda_wait", ("spin", "sleep"),
     "the host's wait for the device: spinning (CUDA's default) or sleeping"),
)  # fmt: skip


def variants(args: argparse.Namespace) -> list[Variant]:
    """Every run to compare: B x overlap x VAE x wait x render size, each with the
    ``--baseline`` package first where one is given."""
    renders = getattr(args, "renders", None) or [None]
    builds = ["baseline", "this"] if getattr(args, "baseline", None) else ["this"]
    depths = getattr(args, "stub_depth", None) or ["on"]
    out = []
    for b, overlap, vae, wait, render, depth, build in itertools.product(
        args.groups, args.overlap, args.vae, args.cuda_wait,
        renders if len(renders) > 1 else [None], depths, builds,
    ):  # fmt: skip
        # One plant has no halves: it runs once, without overlap, whichever was asked.
        v = Variant(b, "off" if b == 1 else overlap, vae, wait, render, depth, build)
        if v not in out:
            out.append(v)
    return out


class StepClock:
    """The ``on_step`` hook (called on the step's thread): wall clock, process CPU time
    and the step thread's CPU time at every step end; calls
    ``on_window("start")`` at the end of warm-up and ``on_window("stop")`` at the end of
    step ``last`` (the run's exports after it are no part of the window)."""

    def __init__(
        self, warmup: int, on_window: Callable[[str], None] | None = None, last: int = -1
    ) -> None:
        self.warmup, self.on_window, self.last = warmup, on_window, last
        self.wall: list[float] = []
        self.cpu: list[float] = []
        self.serial: list[float] = []

    def __call__(self, step: int) -> None:
        self.wall.append(time.perf_counter())
        self.cpu.append(time.process_time())
        self.serial.append(time.thread_time())
        if self.on_window is not None and len(self.wall) == self.warmup:
            self.on_window("start")
        if self.on_window is not None and step == self.last:
            self.on_window("stop")

    def steady(self, b: int) -> dict[str, float]:
        if len(self.wall) < self.warmup + 1:
            raise SystemExit(
                f"error: {len(self.wall)} steps leave no step after {self.warmup} warm-up steps"
            )
        gaps = [t1 - t0 for t0, t1 in itertools.pairwise(self.wall[self.warmup - 1 :])]
        steps = len(gaps)
        cpu = self.cpu[-1] - self.cpu[self.warmup - 1]
        serial = self.serial[-1] - self.serial[self.warmup - 1] if self.serial else math.nan
        median = statistics.median(gaps)
        return {
            "steady_steps": steps,
            "step_ms_median": 1000 * median,
            "step_ms_min": 1000 * min(gaps),
            "plants_per_hour": 3600 * b / (median * STEPS_PER_PLANT),
            "s_per_plant": median * STEPS_PER_PLANT / b,
            "host_core_ms_per_plant_step": 1000 * cpu / (steps * b),
            "host_serial_ms_per_step": 1000 * serial / steps,
            "window_s": self.wall[-1] - self.wall[self.warmup - 1],
        }


class GpuBusy:
    """The GPU's busy share over the steady window: NVML samples every 50 ms where pynvml
    imports, else the torch profiler's kernel intervals; ``share`` stays None on the CPU."""

    def __init__(self, cuda: bool) -> None:
        self.cuda, self.share, self.source = cuda, None, None
        self._nvml: Any = None
        self._samples: list[float] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._prof: Any = None
        self._t0 = 0.0
        if cuda:
            with contextlib.suppress(Exception):  # no pynvml, or no NVML library
                import pynvml

                pynvml.nvmlInit()
                index = os.environ.get("CUDA_VISIBLE_DEVICES", "0").split(",")[0]
                self._nvml = (pynvml, pynvml.nvmlDeviceGetHandleByIndex(int(index)))

    def window(self, event: str) -> None:
        if not self.cuda:
            return
        if event == "stop":
            self._close()
            return
        if self._nvml is not None:
            self._thread = threading.Thread(target=self._sample, daemon=True)
            self._thread.start()
            return
        from torch.profiler import ProfilerActivity, profile

        self._prof = profile(activities=[ProfilerActivity.CUDA])
        self._prof.start()
        self._t0 = time.perf_counter()

    def _sample(self) -> None:
        pynvml, handle = self._nvml
        while not self._stop.wait(NVML_PERIOD_S):
            self._samples.append(pynvml.nvmlDeviceGetUtilizationRates(handle).gpu / 100)

    def finish(self) -> None:
        """Ends the window if the run stopped early (a failure) and leaves ``share`` set."""
        self._close()

    def _close(self) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
            if self._samples:
                self.share, self.source = statistics.fmean(self._samples), "nvml"
        elif self._prof is not None:
            import torch

            torch.cuda.synchronize()
            wall = time.perf_counter() - self._t0
            self._prof.stop()
            prof, self._prof = self._prof, None
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
            self.share, self.source = min(1.0, total / 1e6 / wall), "profiler"


class OneStepTrace:
    """Profiles the step after warm-up (torch profiler: CPU, and CUDA where present) and
    writes it to ``path`` as a Chrome trace."""

    def __init__(self, path: Path, cuda: bool, clock: StepClock) -> None:
        from torch._C._profiler import _ExperimentalConfig
        from torch.profiler import ProfilerActivity, profile

        activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
        self.path, self.clock = path, clock
        # Every thread: the plants' renders and backwards run on a pool's threads.
        every_thread = _ExperimentalConfig(profile_all_threads=True)
        self.prof = profile(activities=activities, experimental_config=every_thread)
        self.active = False

    def __call__(self, step: int) -> None:
        self.clock(step)
        if len(self.clock.wall) == self.clock.warmup:
            self.prof.start()
            self.active = True
        elif self.active:
            self.stop()

    def stop(self) -> None:
        if not self.active:
            return
        self.prof.stop()
        self.active = False
        from plantdreamer.atomic import atomic_path

        self.path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.path) as tmp:
            self.prof.export_chrome_trace(str(tmp))


def build_parts(args: argparse.Namespace) -> Callable[[], Any]:
    """The networks' factory: tiny ones, or full size (random weights) on the device."""
    if args.tiny:
        from plantdreamer.guidance.tiny import tiny_models

        return tiny_models
    from plantdreamer.guidance.full_size import full_size_models

    return lambda: full_size_models(device=args.device)


def resolved(cfgs: list) -> None:
    """Decides the configs' open settings as a run does (a baseline package from before
    ``resolve_plants``: its ``resolve_runtime``, plant by plant)."""
    try:
        from plantdreamer.pipeline.settings.runtime import resolve_plants
    except ImportError:
        from plantdreamer.pipeline.settings.runtime import resolve_runtime

        for cfg in cfgs:
            resolve_runtime(cfg)
        return
    resolve_plants(cfgs)


def train_group(cfgs: list, out: str, **kw: Any) -> dict[str, str]:
    """Trains ``cfgs`` as a group (a folder each under ``out``); the failed plants' errors.
    A ``--baseline`` package from before the one entry (d0ac9b2 and earlier) trains it
    through its own ``generate_group``."""
    try:
        from plantdreamer.pipeline import FolderPerPlant, generate_plants
    except ImportError:
        from plantdreamer.pipeline.group import generate_group

        return dict(generate_group(cfgs, out, show_progress=False, **kw).failed)
    results = generate_plants(cfgs, out, layout=FolderPerPlant(), failures="record",
                              show_progress=False, **kw)  # fmt: skip
    return {r.name: r.error or "" for r in results if not r.done}


def one_run(v: Variant, args: argparse.Namespace, parts: Any, trace: Path | None = None):
    """Trains one group of ``v.b`` plants; returns the run's figures."""
    import torch

    from plantdreamer.guidance.sds import StableDiffusionDepthGuidance
    from plantdreamer.pipeline import GenerateConfig, StepOptions

    cuda = args.device.startswith("cuda")
    cfgs = [
        GenerateConfig.of(
            species="bean", seed=s, steps=args.steps, points=args.points,
            resolution=v.render or args.render, sds_resolution=args.sds, eval_views=1,
            turntable_frames=1, turntable="none", checkpoint_every=args.steps,
            device=args.device, overlap=v.overlap, vae_dtype=v.vae,
        )
        for s in range(v.b)
    ]  # fmt: skip
    guidance: Any
    if args.networks == "stub":  # the host's own work: no network, depth maps still made
        from stub_guidance import StubGuidance

        guidance = StubGuidance(resolution=args.sds, needs_depth=v.stub_depth == "on")
    else:
        guidance = StableDiffusionDepthGuidance(
            species="bean", components=parts, resolution=args.sds, device=args.device,
            vae_dtype=v.vae, seed=0,
        )  # fmt: skip
    busy = GpuBusy(cuda)
    clock = StepClock(args.warmup, busy.window, last=args.steps - 1)
    hook: Callable[[int], None] = clock if trace is None else OneStepTrace(trace, cuda, clock)
    if cuda:
        torch.cuda.reset_peak_memory_stats()
    options = StepOptions(sleeping_wait=v.cuda_wait == "sleep")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        failed = train_group(cfgs, tmp, guidance=guidance, on_step=hook, options=options)
        wall = time.perf_counter() - t0
        busy.finish()
        if isinstance(hook, OneStepTrace):
            hook.stop()
        if failed:
            raise SystemExit(f"error: plants failed: {failed}")
        runs = [json.loads(p.read_text()) for p in sorted(Path(tmp).glob("*/run.json"))]
    timings = {k: sum(r["timings_s"].get(k, 0.0) for r in runs) for k in PHASES}
    out: dict[str, Any] = {"B": v.b, "overlap": v.overlap, "vae": v.vae,
                           "cuda_wait": v.cuda_wait, "render": v.render or args.render,
                           "build": v.build, "stub_depth": v.stub_depth}  # fmt: skip
    out |= clock.steady(v.b)
    out["gpu_busy"], out["gpu_busy_source"] = busy.share, busy.source
    # The device's side beside the host's: its busy time per plant-step over the window.
    out["device_ms_per_plant_step"] = (
        None if busy.share is None
        else 1000 * busy.share * out["window_s"] / (out["steady_steps"] * v.b)
    )  # fmt: skip
    out["phases_ms"] = {k: 1000 * timings.get(k, 0.0) / args.steps for k in PHASES}
    out["gaussians_final"] = runs[0]["gaussians"]["final"]  # plant 0's
    reference = raster_alone_core_ms(cfgs, args.warmup, args.steps - 1)
    out["raster_core_ms_per_plant"] = reference["core_ms"]
    out["raster_renders"] = reference["renders"]
    out["raster_range"] = reference["range"]
    out["host_to_raster"] = out["host_core_ms_per_plant_step"] / out["raster_core_ms_per_plant"]
    out["peak_cuda_gib"] = torch.cuda.max_memory_allocated() / 2**30 if cuda else None
    out["wall_s"] = wall
    return out


# The rasterizer-alone reference: forward + backward calls over the steady window's cameras,
# taken from the first REFERENCE_PLANTS plants of the group, REFERENCE_RENDERS in all.
REFERENCE_PLANTS = 4
REFERENCE_RENDERS = 16


def window_cameras(sampler: Any, first: int, last: int, count: int) -> list[Any]:
    """``count`` of the cameras a fresh plant's ``sampler`` gives it in steps ``first..last``
    (one draw per step, as the trainer takes them), evenly spread, none twice."""
    cameras = [sampler.sample() for _ in range(last + 1)][first:]
    picks = sorted({round(i * (len(cameras) - 1) / max(count - 1, 1)) for i in range(count)})
    return [cameras[i] for i in picks]


def forward_backward_s(model: Any, camera: Any, background: float) -> float:
    """Process CPU seconds of one render of ``model`` and its backward (every colour's
    gradient one)."""
    import torch

    t0 = time.process_time()
    image, _, _ = model.render([camera], background)
    torch.autograd.backward(image, torch.ones_like(image))
    return time.process_time() - t0


def raster_alone_core_ms(cfgs: list[Any], first: int, last: int) -> dict[str, Any]:
    """The rasterizer's own work on the window's renders: process CPU time of one forward
    and backward (``GaussianModel.render`` of a plant's initial Gaussians, every colour's
    gradient one) from each of ``REFERENCE_RENDERS`` cameras the plants trained on in
    steps ``first..last`` (spread over the first ``REFERENCE_PLANTS`` plants), after one
    call left out (first-touch of its buffers). The mean, as the host's figure is over
    every plant's cameras: one camera is no reference (the close ones cover more pixels;
    ``range``: the cheapest and the costliest call over the mean). The host's core-ms per
    plant-step over this is what the step adds to the rasterizer."""
    import copy

    from plantdreamer.pipeline.state.run_state import RunState

    plants = [copy.deepcopy(cfg) for cfg in cfgs[:REFERENCE_PLANTS]]
    resolved(plants)
    times = []
    for k, cfg in enumerate(plants):
        share = REFERENCE_RENDERS // len(plants) + (k < REFERENCE_RENDERS % len(plants))
        state = RunState.fresh(cfg, show_progress=False)
        cameras = window_cameras(state.sampler, first, last, share)
        background = cfg.train.background
        if k == 0:  # left out: it touches its buffers first
            forward_backward_s(state.model, cameras[0], background)
        times += [forward_backward_s(state.model, c, background) for c in cameras]
    mean = statistics.mean(times)
    return {
        "core_ms": 1000 * mean,
        "renders": len(times),
        "range": [min(times) / mean, max(times) / mean],
    }


def run_all(args: argparse.Namespace) -> dict[str, Any]:
    """Every variant, interleaved over the repeats: ``{"groups": {label: median run}}``,
    with each run's repeats under ``repeats``."""
    runs: dict[Variant, list[dict[str, Any]]] = {v: [] for v in variants(args)}
    make = build_parts(args)
    # One set of networks per VAE precision, built once (the guidance casts its VAE in
    # place, so the precisions do not share one set).
    parts: dict[str, Any] = {}
    for _ in range(args.repeats):
        for v in runs:
            if getattr(args, "baseline", None):  # each build in a process of its own
                runs[v].append(child_run(v, args))
            else:
                if v.vae not in parts:
                    parts[v.vae] = make()
                runs[v].append(one_run(v, args, parts[v.vae]))
            print(v.label, json.dumps(runs[v][-1]), flush=True)
    groups = {}
    for v, reps in runs.items():
        row = dict(min(reps, key=lambda r: r["step_ms_median"]))  # keys of one run
        for key, value in reps[0].items():
            if isinstance(value, float) and all(isinstance(r[key], float) for r in reps):
                row[key] = statistics.median(r[key] for r in reps)
        row["step_ms_median_min"] = min(r["step_ms_median"] for r in reps)
        row["host_core_ms_per_plant_step_min"] = min(r["host_core_ms_per_plant_step"] for r in reps)
        row["repeats"] = reps
        groups[v.label] = row
    return {
        "device": args.device,
        "host": host_line(),
        "networks": networks_text(args),
        "points": args.points,
        "render": getattr(args, "renders", None) or args.render,
        "sds": args.sds,
        "baseline": None if not getattr(args, "baseline", None) else str(args.baseline),
        "steps": args.steps,
        "warmup": args.warmup,
        "repeats": args.repeats,
        "groups": groups,
    }


def child_run(v: Variant, args: argparse.Namespace) -> dict[str, Any]:
    """``one_run`` in a fresh process: with the package under ``--baseline`` first on its
    path for the baseline build, else with this tree's (the two alike in every other way)."""
    import subprocess

    env = dict(os.environ)
    if v.build == "baseline":
        env["PYTHONPATH"] = os.pathsep.join(
            p for p in (str(args.baseline), env.get("PYTHONPATH")) if p
        )
    settings = {k: str(val) if isinstance(val, Path) else val for k, val in vars(args).items()}
    job = json.dumps({"variant": dataclasses.asdict(v), "args": settings})
    done = subprocess.run(
        [sys.executable, __file__, "--child", job], env=env, capture_output=True, text=True
    )
    if done.returncode != 0:
        raise SystemExit(f"error: the {v.label} run failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def run_child(job: str) -> int:
    """One ``one_run`` of a ``child_run`` job; its row is the last line printed."""
    import plantdreamer

    spec = json.loads(job)
    args = argparse.Namespace(**spec["args"])
    v = Variant(**spec["variant"])
    row = one_run(v, args, None if args.networks == "stub" else build_parts(args)())
    row["package"] = str(Path(plantdreamer.__file__).parent)
    print(json.dumps(row))
    return 0


def networks_text(args: argparse.Namespace) -> str:
    if args.networks == "stub":
        return "no (--networks stub: a fixed render gradient, depth maps made)"
    return "tiny" if args.tiny else "full size (SD 2.1-base), random weights"


def table(report: dict[str, Any], command: str) -> list[str]:
    def num(x: Any, fmt: str = "{:.1f}") -> str:
        return "-" if x is None or not math.isfinite(x) else fmt.format(x)

    lines = [
        "## Plants per hour in the steady state (`benches/bench_throughput.py`)",
        "",
        f"Command: `{command}`; device {report['device']}, host {report['host']}; "
        f"{report['networks']} networks, {report['points']} points per plant, render "
        f"{report['render']} px, SDS {report['sds']} px, {report['steps']} steps of which "
        f"{report['warmup']} warm-up, {report['repeats']} interleaved repeats (median of "
        "the runs; min in brackets). Step ms: median wall time between step ends after "
        "warm-up; host core-ms: process CPU time per plant-step over the same window; "
        "serial ms: the step thread's own CPU time per step; raster core-ms: the "
        "rasterizer alone, one forward and backward at the render size (process CPU time, "
        f"the mean over {REFERENCE_RENDERS} cameras the first plants trained on in the "
        "window), and the "
        "host's core-ms per plant-step over it; phases: ms "
        "per group step (the plants' shares summed), means over every step."
        + (
            f" Build: `baseline` is the package in `{report['baseline']}`, `this` this "
            "tree's, each run in a process of its own, interleaved."
            if report.get("baseline")
            else ""
        ),
        "",
        "| build | B | render | overlap | VAE | CUDA wait | "
        "ms per step | plants per hour | host core-ms per plant-step | host serial ms per "
        "step | raster core-ms (host / raster) | GPU busy | device ms per plant-step | "
        "peak GPU GiB | " + " | ".join(PHASES) + " |",
        "|---|---:|---:|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"
        + "---:|" * len(PHASES),
    ]
    for row in report["groups"].values():
        phases = " | ".join(num(row["phases_ms"][p]) for p in PHASES)
        lines.append(
            f"| {row['build']}{' (no depth maps)' if row.get('stub_depth') == 'off' else ''} | "
            f"{row['B']} | {row['render']} | {row['overlap']} | {row['vae']} | "
            f"{row['cuda_wait'] if report['device'] != 'cpu' else '-'} | "
            f"{num(row['step_ms_median'])} ({num(row['step_ms_median_min'])}) | "
            f"{num(row['plants_per_hour'], '{:.2f}')} | "
            f"{num(row['host_core_ms_per_plant_step'])} "
            f"({num(row['host_core_ms_per_plant_step_min'])}) | "
            f"{num(row['host_serial_ms_per_step'])} | "
            f"{num(row['raster_core_ms_per_plant'])} ({num(row['host_to_raster'], '{:.2f}')}x) | "
            f"{num(row['gpu_busy'], '{:.0%}')} | {num(row.get('device_ms_per_plant_step'))} | "
            f"{num(row['peak_cuda_gib'], '{:.1f}')} | "
            f"{phases} |"
        )
    return lines


def guidance_times(n: int, folder: Path, shared: bool) -> list[float]:
    """Seconds to build each of ``n`` plants' guidance (tiny models from ``folder``)."""
    from plantdreamer.dataset.worker import ModelCache
    from plantdreamer.pipeline import GenerateConfig
    from plantdreamer.pipeline.settings.group_settings import GroupSettings
    from plantdreamer.pipeline.settings.runtime import resolve_plants

    cache, times = ModelCache(), []
    for seed in range(n):
        cfg = GenerateConfig.of(
            species="bean", seed=seed, base_model=str(folder / "base"),
            controlnet=str(folder / "controlnet"), device="cpu", sds_resolution=64,
        )  # fmt: skip
        resolve_plants([cfg])
        if not shared:
            cache = ModelCache()
        t0 = time.perf_counter()
        cache.guidance_for(GroupSettings.of([cfg]))
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
        f"Command: `{command.strip()}`, on {host_line()}, no CUDA GPU on the benchmark "
        f"machine. Building the guidance of {args.loading} plants (tiny random-weight models "
        "saved in the hub's layout, CPU, float32), the two ways alternating over "
        f"{args.repeats} repeats; min / median.",
        "",
        f"| models loaded | per plant, ms | all {args.loading} plants, s |",
        "|---|---|---|",
    ]
    for name, times in runs.items():
        per = f"{1000 * min(times):.1f} / {1000 * statistics.median(times):.1f}"
        total = f"{min(totals[name]):.2f} / {statistics.median(totals[name]):.2f}"
        lines.append(f"| {name} | {per} | {total} |")
    return lines


def add_arguments(p: argparse.ArgumentParser, *, gpu_checks: bool = False) -> None:
    """The run settings (``scripts/gpu_checks.py throughput`` shares them)."""
    p.add_argument("--groups", type=int, nargs="+", help="B values (default 1 8 16 32; "
                   "--tiny: 1 4 8)")  # fmt: skip
    p.add_argument("--overlap", nargs="+", choices=("off", "on"), default=["off", "on"])
    p.add_argument("--vae", nargs="+", choices=("float32", "bfloat16"), help="VAE precision "
                   "(default float32 bfloat16 on CUDA, float32 on the CPU)")  # fmt: skip
    defaults = {f.name: f.default for f in dataclasses.fields(Variant)}
    for name, choices, text in SWITCHES:
        flag = "--" + name.replace("_", "-")
        p.add_argument(flag, nargs="+", choices=choices, default=[defaults[name]], help=text)
    p.add_argument("--steps", type=int, default=None if gpu_checks else 24)
    p.add_argument("--warmup", type=int, default=7, help="steps left out of the steady state")
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--points", type=int, default=100_000)
    p.add_argument("--render", type=int, nargs="+", help="render sizes, each a run of its "
                   "own (768; --tiny: 128)")  # fmt: skip
    p.add_argument("--baseline", type=Path, help="a folder holding an earlier plantdreamer "
                   "package (a checkout's python/ or an unpacked wheel): every run is made "
                   "with it too, interleaved, each in a process of its own")  # fmt: skip
    p.add_argument("--sds", type=int, help="SDS size (512; --tiny: 64)")
    p.add_argument("--tiny", action="store_true", help="tiny networks on the CPU")
    p.add_argument("--networks", choices=("real", "stub"), default="real",
                   help="stub: no network runs, the guidance returns a fixed render gradient "
                   "(the depth maps are still made): the host's own work alone")  # fmt: skip
    p.add_argument("--stub-depth", nargs="+", choices=("on", "off"), default=["on"],
                   help="--networks stub: the depth conditioning made (on) or left out "
                   "(off), each a run: what the depth maps cost the host")  # fmt: skip
    p.add_argument("--device", help="cuda where present, else cpu (--tiny: cpu)")
    p.add_argument("--trace", type=Path, help="Chrome trace of one steady step (first run)")


def resolve(args: argparse.Namespace) -> argparse.Namespace:
    """Fills the machine-dependent defaults; an impossible choice is one clear error."""
    import torch

    cuda = torch.cuda.is_available()
    args.tiny = args.tiny or not cuda
    args.device = args.device or ("cuda" if cuda and not args.tiny else "cpu")
    if args.device.startswith("cuda") and not cuda:
        raise SystemExit("error: --device cuda asked for, but torch sees no CUDA GPU")
    args.groups = args.groups or ([1, 4, 8] if args.tiny else [1, 8, 16, 32])
    args.vae = args.vae or (["float32"] if args.tiny else ["float32", "bfloat16"])
    args.renders = args.render or [128 if args.tiny else 768]
    args.render = args.renders[0]
    if args.baseline is not None and not (args.baseline / "plantdreamer").is_dir():
        raise SystemExit(f"error: --baseline {args.baseline} holds no plantdreamer package")
    args.sds = args.sds or (64 if args.tiny else 512)
    args.steps = args.steps or 24
    if not args.device.startswith("cuda"):
        args.cuda_wait = ["sleep"]  # no device to wait for: one run, not two the same
    if args.warmup < 1 or args.steps <= args.warmup:
        raise SystemExit(f"error: --steps ({args.steps}) must exceed --warmup ({args.warmup}) "
                         "and --warmup be at least 1")  # fmt: skip
    if args.stub_depth != ["on"] and args.networks != "stub":
        raise SystemExit("error: --stub-depth is for --networks stub (real networks need depth)")
    if min(args.groups) < 1:
        raise SystemExit("error: --groups takes B >= 1")
    return args


def trace_one(args: argparse.Namespace) -> dict[str, Any]:
    """One run of the first variant with one steady step profiled into ``args.trace``."""
    v = variants(args)[0]
    row = one_run(v, args, build_parts(args)(), trace=args.trace)
    print(f"trace of one step of B = {v.b} ({v.label}) written to {args.trace}")
    return row


def main() -> int:
    if sys.argv[1:2] == ["--child"]:
        return run_child(sys.argv[2])
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    parser.add_argument("--loading", type=int, metavar="N", help="plants of the loading bench")
    # By default a run's table goes under results/runs/ (not collected into BENCHMARKS.md:
    # results/throughput.md is the written account of the runs, which cites them); the
    # loading bench's section is collected (results/throughput_loading.md).
    parser.add_argument("--out", type=Path, help="the table (and .json beside it)")
    args = parser.parse_args()
    from plantdreamer.atomic import write_json, write_text

    if args.loading:
        args.repeats = max(args.repeats, 3)
        lines = loading(args)
        name = "throughput_loading.md"
        write_text(
            args.out.with_name(name) if args.out else RESULTS / name, "\n".join(lines) + "\n"
        )
        print("\n".join(lines))
        return 0
    resolve(args)
    if args.trace is not None:
        trace_one(args)
        return 0
    report = run_all(args)
    command = "python benches/bench_throughput.py " + " ".join(sys.argv[1:])
    lines = table(report, command.strip())
    args.out = args.out or RESULTS / "runs" / "throughput.md"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_text(args.out, "\n".join(lines) + "\n")
    write_json(args.out.with_suffix(".json"), report)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
