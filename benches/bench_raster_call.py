"""The whole `plantdreamer.rasterization` call against the native kernels, and torch's
OpenMP wait policy inside a training step. Writes benches/results/raster_call.md (+ .json).

    python benches/bench_raster_call.py [--rounds 4] [--reps 5]

Each round starts one process per OpenMP setting, alternating (the policy is read once,
when torch loads): PASSIVE (what `import plantdreamer` sets) and libgomp's default spin
(GOMP_SPINCOUNT=300000). A process runs, per repetition and interleaved: the native
forward, the public forward (no grad; the difference of the two is the wrapper's cost),
the native backward, and a training step (public forward with a background, MSE loss,
backward, Adam) on the 100k bench plant with SH degree 3 at 512^2. Min and median over
all repetitions of all rounds, after one untimed repetition per process. On a loaded
machine "public - native" is the difference of two noisy calls; the "wrapper alone" rows
time the public call with the kernels answered from a prepared call, which isolates the
Python side (copies, checks, wrapping, the background blend and autograd).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

BENCHES = Path(__file__).resolve().parent
RESULTS = BENCHES / "results"
COMMAND = "python benches/bench_raster_call.py"
SETTINGS = {
    "PASSIVE (plantdreamer's default)": {},
    "libgomp default (spin 300000)": {"GOMP_SPINCOUNT": "300000"},
}
SERIES = {
    "native_forward": "native forward (`_core.rasterize_forward_many`, one scene)",
    "public_forward": "public forward (`rasterization`, no grad)",
    "wrapper": "public - native, same repetition",
    "native_backward": "native backward (`_core.rasterize_backward_many`, one scene)",
    "step_render": "training step: forward with background",
    "step_backward": "training step: loss + backward",
    "step_adam": "training step: Adam",
    "step": "training step: total",
    "wrapper_forward": "wrapper alone: public forward, no grad",
    "wrapper_step": "wrapper alone: forward with background + backward",
}


class CachedCore:
    """`plantdreamer._core` with the rasterizer calls answered from one prepared call, so
    that timing `rasterization` measures the Python side alone (kernels take no time)."""

    def __init__(self, core, forward: dict, backward: dict) -> None:
        self.core, self.forward, self.backward = core, forward, backward

    def __getattr__(self, name: str):
        return getattr(self.core, name)

    def rasterize_forward_many(self, scenes, **kwargs) -> list[dict]:
        return [dict(self.forward) for _ in scenes]

    def rasterize_backward_many(self, states, *args, **kwargs) -> list[dict]:
        return [dict(self.backward) for _ in states]


def child(n: int, size: int, reps: int) -> dict[str, list[float]]:
    """Times (s) of every series in this process (its OpenMP setting is already fixed)."""
    sys.path.insert(0, str(BENCHES))
    sys.path.insert(0, str(BENCHES.parent / "tests"))
    import numpy as np
    import torch
    from raster_scene import orbit_cameras, synthetic_plant

    import raster_native as native
    from plantdreamer import rasterization

    scene = synthetic_plant(n, sh_degree=3)
    viewmats, ks = orbit_cameras(size, size)
    arrays = [x.numpy() for x in scene]
    bg = torch.full((1, 3), 0.75)
    params = [x.clone().requires_grad_(True) for x in scene]
    adam = torch.optim.Adam(params, lr=1e-3)
    times: dict[str, list[float]] = {k: [] for k in SERIES}
    v_render = v_alpha = None
    for rep in range(reps + 1):
        t0 = time.perf_counter()
        out = native.forward(*arrays, viewmats.numpy(), ks.numpy(), size, size, sh_degree=3)
        t1 = time.perf_counter()
        if v_render is None:
            v_render = np.full(out["render"].shape, 1e-3, np.float32)
            v_alpha = np.full(out["alpha"].shape, 1e-3, np.float32)
        t2 = time.perf_counter()
        native.backward(out["state"], v_render, v_alpha)
        t3 = time.perf_counter()
        del out
        with torch.no_grad():
            t4 = time.perf_counter()
            rasterization(*scene, viewmats, ks, size, size, sh_degree=3)
            t5 = time.perf_counter()
        img, _, _ = rasterization(*params, viewmats, ks, size, size, sh_degree=3, backgrounds=bg)
        t6 = time.perf_counter()
        loss = (img - 0.5).square().mean()
        adam.zero_grad(set_to_none=True)
        loss.backward()
        t7 = time.perf_counter()
        adam.step()
        t8 = time.perf_counter()
        del img, loss
        if rep == 0:  # warm-up: pools, allocator, Adam's state
            continue
        for key, value in (
            ("native_forward", t1 - t0),
            ("native_backward", t3 - t2),
            ("public_forward", t5 - t4),
            ("wrapper", (t5 - t4) - (t1 - t0)),
            ("step_render", t6 - t5),
            ("step_backward", t7 - t6),
            ("step_adam", t8 - t7),
            ("step", t8 - t5),
        ):
            times[key].append(value)
    wrapper_alone(scene, params, viewmats, ks, size, bg, reps, times)
    return times


def wrapper_alone(scene, params, viewmats, ks, size, bg, reps, times) -> None:
    """Fills the wrapper-alone series: the public calls with the kernels answered from a
    prepared call (`CachedCore`), 20 calls per repetition."""
    import numpy as np
    import torch

    import raster_native as native
    from plantdreamer import _core, rasterization, rasterizer

    arrays = [x.numpy() for x in scene]
    out = native.forward(*arrays, viewmats.numpy(), ks.numpy(), size, size, sh_degree=3)
    v_render = np.full(out["render"].shape, 1e-3, np.float32)
    v_alpha = np.full(out["alpha"].shape, 1e-3, np.float32)
    grads = native.backward(out["state"], v_render, v_alpha)
    rasterizer._core = CachedCore(_core, out, grads)  # type: ignore[assignment]
    try:
        for _ in range(reps * 20):
            t0 = time.perf_counter()
            rasterization(*scene, viewmats, ks, size, size, sh_degree=3)
            for p in params:
                p.grad = None  # as zero_grad(set_to_none=True): the gradients are taken over
            t1 = time.perf_counter()
            img, _, _ = rasterization(
                *params, viewmats, ks, size, size, sh_degree=3, backgrounds=bg
            )
            img.backward(torch.ones_like(img))
            t2 = time.perf_counter()
            times["wrapper_forward"].append(t1 - t0)
            times["wrapper_step"].append(t2 - t1)
    finally:
        rasterizer._core = _core


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.n, args.size, args.reps)))
        return
    runs: dict[str, dict[str, list[float]]] = {s: {k: [] for k in SERIES} for s in SETTINGS}
    loads = []
    for _ in range(args.rounds):
        for setting, extra in SETTINGS.items():
            env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY",)}
            env.pop("GOMP_SPINCOUNT", None)
            env.update(extra)
            argv = [sys.executable, __file__, "--child", "--reps", str(args.reps)]
            argv += ["--n", str(args.n), "--size", str(args.size)]
            loads.append(os.getloadavg()[0])
            done = subprocess.run(argv, env=env, capture_output=True, text=True, check=True)
            for key, values in json.loads(done.stdout.splitlines()[-1]).items():
                runs[setting][key].extend(values)

    def cell(values: list[float]) -> str:
        return f"{min(values) * 1e3:.2f} / {statistics.median(values) * 1e3:.2f}"

    rows = [
        f"| {label} | " + " | ".join(cell(runs[s][key]) for s in SETTINGS) + " |"
        for key, label in SERIES.items()
    ]
    table = (
        "| ms, min / median | "
        + " | ".join(SETTINGS)
        + " |\n|---|"
        + "---|" * len(SETTINGS)
        + "\n"
        + "\n".join(rows)
    )
    md = f"""### Whole call and threads (`benches/bench_raster_call.py`)

Command: `{COMMAND} --rounds {args.rounds} --reps {args.reps}`. {args.n:,} Gaussians (the
bench plant, SH degree 3) at {args.size}^2, rayon's global pool
({len(os.sched_getaffinity(0))} cores); {args.rounds} rounds x {args.reps} repetitions per
setting, alternating processes ({args.reps * 20} calls per process for the wrapper-alone
rows). 1-minute load average at the start of each process: {min(loads):.1f} to
{max(loads):.1f}.

{table}

How to read it: the wrapper-alone rows are the Python side's whole cost (the goal is under
1 ms for the forward at 100k). "public - native" is the difference of two calls that each
vary by tens of milliseconds on a loaded machine, so it can come out negative. The kernel
rows follow the machine's load and speed (compare them with the forward table's run only
through its calibration line); what they show is the spread between the two OpenMP settings.
"""
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "raster_call.md").write_text(md)
    (RESULTS / "raster_call.json").write_text(json.dumps({"loads": loads, "runs": runs}, indent=1))
    print(md)


if __name__ == "__main__":
    main()
