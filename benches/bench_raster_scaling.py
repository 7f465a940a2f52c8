"""Rasterizer scaling: forward and backward time and the saved state's size, from 10k to 3M
Gaussians at 512^2 and 1024^2. Writes benches/results/raster_scaling.md (+ .json).

    python benches/bench_raster_scaling.py [--quick]

Native calls (`plantdreamer._core`'s pair with one scene, the kernels without the Python
wrapper) on rayon's global pool (every core this process may use). Each repetition is one
forward and one backward of that forward (dL/d(render) and dL/d(alpha) constant); min and
median over the repetitions after one untimed warm-up, fewer repetitions for the large
scenes.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

BENCHES = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCHES))
sys.path.insert(0, str(BENCHES.parent / "tests"))

from raster_scene import orbit_cameras, synthetic_plant  # noqa: E402

import raster_native as native  # noqa: E402
from plantdreamer import _core  # noqa: E402

RESULTS = BENCHES / "results"
COMMAND = "python benches/bench_raster_scaling.py"
# Timed repetitions per scene size: a 3M-Gaussian forward + backward takes seconds here.
REPS = {10_000: 9, 100_000: 7, 1_000_000: 3, 3_000_000: 2}


def measure(n: int, size: int, reps: int) -> dict:
    arrays = [x.numpy() for x in synthetic_plant(n)]
    viewmats, ks = (x.numpy() for x in orbit_cameras(size, size))
    fwd, bwd, out = [], [], None
    for rep in range(reps + 1):
        out = None  # free the previous state before the next forward
        t0 = time.perf_counter()
        out = native.forward(*arrays, viewmats, ks, size, size)
        t1 = time.perf_counter()
        v_render = np.full(out["render"].shape, 1e-3, np.float32)
        v_alpha = np.full(out["alpha"].shape, 1e-3, np.float32)
        t2 = time.perf_counter()
        native.backward(out["state"], v_render, v_alpha)
        t3 = time.perf_counter()
        if rep:  # the first call warms the pool and the allocator
            fwd.append(t1 - t0)
            bwd.append(t3 - t2)
    assert out is not None
    return {
        "n": n,
        "size": size,
        "reps": reps,
        "forward_ms": [t * 1e3 for t in fwd],
        "backward_ms": [t * 1e3 for t in bwd],
        "intersections": int(out["n_intersections"][0]),
        "state_mib": out["state"].nbytes / 2**20,
    }


def row(r: dict) -> str:
    f, b = r["forward_ms"], r["backward_ms"]
    return (
        f"| {r['n']:,} | {r['size']}^2 | {r['intersections']:,} | "
        f"{min(f):.1f} ({statistics.median(f):.1f}) | {min(b):.1f} ({statistics.median(b):.1f}) | "
        f"{statistics.median(b) / statistics.median(f):.2f} | {r['state_mib']:.0f} | {r['reps']} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10k and 100k only, 2 repetitions")
    args = parser.parse_args()
    counts = (10_000, 100_000) if args.quick else tuple(REPS)
    results = []
    load_before = os.getloadavg()[0]
    for n in counts:
        for size in (512, 1024):
            results.append(measure(n, size, 2 if args.quick else REPS[n]))
            print(row(results[-1]), flush=True)
    table = (
        "| Gaussians | image | tile intersections | forward, min (median) ms | "
        "backward, min (median) ms | backward / forward (medians) | saved state (MiB) | "
        "repetitions |\n|---|---|---|---|---|---|---|---|\n" + "\n".join(map(row, results))
    )
    md = f"""## Rasterizer scaling (`benches/bench_raster_scaling.py`)

Command: `{COMMAND}`. Scene: the synthetic plant of `benches/raster_scene.py` at each size,
one orbit camera. Native forward and backward on rayon's global pool
({_core.info()["threads"]} threads); min and median over the repetitions after one warm-up.
The saved state is `RasterState.nbytes`: what a forward keeps for its backward (a copy of
the inputs, projected splats and features, tile lists, final transmittance and last index
per pixel), so O(N + pixels + intersections). 1-minute load average of the machine:
{load_before:.1f} at the start, {os.getloadavg()[0]:.1f} at the end.

{table}
"""
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "raster_scaling.md").write_text(md)
    (RESULTS / "raster_scaling.json").write_text(json.dumps(results, indent=1))
    print(md)


if __name__ == "__main__":
    main()
