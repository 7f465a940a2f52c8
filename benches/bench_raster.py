"""Rasterizer benchmarks: forward speed, time against error, profile, forward + backward,
peak memory of a training step. Writes benches/results/raster.md (+ raster.json).

    python benches/bench_raster.py [--quick]

Timings are wall-clock minima over repetitions: the machine is shared with other builds,
and the minimum is the least disturbed run. Threads are set per call (`threads=`).
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
from pathlib import Path

import numpy as np
import torch

BENCHES = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCHES))
sys.path.insert(0, str(BENCHES.parent / "tests"))

from raster_scene import orbit_cameras, synthetic_plant  # noqa: E402

import raster_native as native  # noqa: E402
import raster_reference as ref  # noqa: E402
from plantdreamer import _core, rasterization  # noqa: E402

RESULTS = BENCHES / "results"
COMMAND = "python benches/bench_raster.py"


def arrays(scene):
    return [x.numpy() for x in scene]


def forward_times(scene, viewmats, ks, size, threads, reps, **kw):
    """Wall times (s) of reps calls after one untimed warm-up call, and the last output.

    The warm-up matters: the first call on a thread pool after another pool ran finds cold
    caches and allocator heaps without free pages (up to ~30% slower at 100k)."""
    times, out = [], None
    native.forward(*arrays(scene), viewmats.numpy(), ks.numpy(), size, size, threads=threads, **kw)
    for _ in range(reps):
        t = time.perf_counter()
        out = native.forward(
            *arrays(scene), viewmats.numpy(), ks.numpy(), size, size, threads=threads, **kw
        )
        times.append(time.perf_counter() - t)
    return times, out


def forward(scene, viewmats, ks, size, threads, reps, **kw):
    """Min wall time (s) over reps and the last output."""
    times, out = forward_times(scene, viewmats, ks, size, threads, reps, **kw)
    return min(times), out


def calibration_ms() -> float:
    """Wall time of a fixed pure-Python loop: how fast the machine is right now."""
    t = time.perf_counter()
    acc = 0
    for i in range(300_000):
        acc += i * i
    return (time.perf_counter() - t) * 1e3


CALIBRATION: list[float] = []


def forward_table(reps: int, sizes, counts) -> tuple[str, list[dict]]:
    """Forward times; for 100k and fewer Gaussians the calls are spread over several rounds
    through all sizes and thread counts, so that a slow spell of the machine does not land
    on one row only."""
    rows, data = [], []
    for n in counts:
        scene = synthetic_plant(n)
        cams = {size: orbit_cameras(size, size) for size in sizes}
        # 1M-Gaussian calls take ~0.2-0.5 s each: fewer repetitions there, in one round.
        rounds = ROUNDS if n <= 100_000 else 1
        per_round = max(1, reps // rounds) if n <= 100_000 else max(2, reps // 3)
        times: dict[tuple[int, int], list[float]] = {}
        outs = {}
        blocks = [(size, threads) for size in sizes for threads in (1, 2)]
        for r in range(rounds):
            # A fixed but shuffled order per round, so that slow spells of the machine do
            # not fall on the same rows every round; a short rest before each block.
            random.Random(r).shuffle(blocks)
            for size, threads in blocks:
                time.sleep(0.2)
                CALIBRATION.append(calibration_ms())
                t, outs[size] = forward_times(scene, *cams[size], size, threads, per_round)
                times.setdefault((size, threads), []).extend(t)
        for size in sizes:
            out = outs[size]
            best = {th: min(times[size, th]) for th in (1, 2)}
            med = {th: float(np.median(times[size, th])) for th in (1, 2)}
            tiles = ((size + 15) // 16) ** 2
            isect = int(out["n_intersections"][0])
            nonempty = int((out["alpha"][0] > 0).sum())
            rows.append(
                f"| {n:,} | {size}x{size} | {best[1] * 1e3:.1f} ({med[1] * 1e3:.1f}) | "
                f"{best[2] * 1e3:.1f} ({med[2] * 1e3:.1f}) | "
                f"{int(out['n_visible'][0]):,} | {isect:,} | {isect / tiles:.1f} | "
                f"{nonempty / size**2:.2f} |"
            )
            data.append(
                {
                    "n": n,
                    "size": size,
                    "calls": len(times[size, 2]),
                    "ms_1_thread": best[1] * 1e3,
                    "ms_2_threads": best[2] * 1e3,
                    "median_ms_1_thread": med[1] * 1e3,
                    "median_ms_2_threads": med[2] * 1e3,
                    "visible": int(out["n_visible"][0]),
                    "intersections": isect,
                }
            )
            print(rows[-1], flush=True)
    table = (
        "| Gaussians | image | 1 thread, min (median) ms | 2 threads, min (median) ms | visible "
        "| tile intersections "
        "| intersections per tile | covered fraction |\n|---|---|---|---|---|---|---|---|\n"
        + "\n".join(rows)
    )
    return table, data


# Rounds through all sizes and thread counts for the forward table.
ROUNDS = 5


def error_vs_reference(size: int, n: int, **kw) -> tuple[float, float, float]:
    """(max, 99.9th percentile, mean) abs RGB+alpha error against the float64 reference."""
    scene = synthetic_plant(n, seed=1)
    viewmats, ks = orbit_cameras(size, size)
    out = native.forward(*arrays(scene), viewmats.numpy(), ks.numpy(), size, size, **kw)
    key = (size, n)
    if key not in _REFERENCE_CACHE:
        _REFERENCE_CACHE[key] = ref.render(
            *[x.double() for x in scene], viewmats[0].double(), ks[0].double(), size, size
        )
    want, want_alpha = _REFERENCE_CACHE[key]
    err = np.concatenate(
        [
            np.abs(out["render"][0] - want.numpy()).ravel(),
            np.abs(out["alpha"][0] - want_alpha.numpy()).ravel(),
        ]
    )
    return float(err.max()), float(np.quantile(err, 0.999)), float(err.mean())


_REFERENCE_CACHE: dict = {}

KNOBS = [
    ("defaults: opacity-aware, ellipse test, tile 32, T_min 1e-4", {}),
    ("footprint 3 sigma", {"footprint_sigma": 3.0}),
    ("footprint 3.33 sigma", {"footprint_sigma": 3.33}),
    ("no tile-ellipse test", {"tile_ellipse": False}),
    (
        "3 sigma, no ellipse test (original 3DGS-like)",
        {"footprint_sigma": 3.0, "tile_ellipse": False},
    ),
    ("tile 8", {"tile_size": 8}),
    ("tile 16 (gsplat's default)", {"tile_size": 16}),
    ("tile 64", {"tile_size": 64}),
    ("T_min 1e-3", {"t_min": 1e-3}),
    ("T_min 1e-2", {"t_min": 1e-2}),
    ("T_min 0 (no early stop)", {"t_min": 0.0}),
    ("scalar blending kernel (simd=False)", {"simd": False}),
]


def knob_table(reps: int, err_size: int, err_n: int) -> tuple[str, list[dict]]:
    scene = synthetic_plant(100_000)
    viewmats, ks = orbit_cameras(512, 512)
    rows, data = [], []
    for name, kw in KNOBS:
        t, out = forward(scene, viewmats, ks, 512, 2, reps, **kw)
        mx, p999, mean = error_vs_reference(err_size, err_n, **kw)
        isect = int(out["n_intersections"][0])
        rows.append(f"| {name} | {t * 1e3:.1f} | {isect:,} | {mx:.2e} | {p999:.2e} | {mean:.2e} |")
        data.append(
            {
                "knob": name,
                "ms": t * 1e3,
                "intersections": isect,
                "max": mx,
                "p999": p999,
                "mean": mean,
            }
        )
        print(rows[-1], flush=True)
    table = (
        "| setting | time, 100k @ 512^2, 2 threads (ms) | intersections | max error | "
        "99.9th pct error | mean error |\n|---|---|---|---|---|---|\n" + "\n".join(rows)
    )
    return table, data


def profile_table(reps: int) -> tuple[str, dict]:
    """Table of the 1-thread stage times, and the blending share per scene."""
    rows, blend_share = [], {}
    for n, size in ((100_000, 512), (100_000, 768), (1_000_000, 512)):
        scene = synthetic_plant(n)
        viewmats, ks = orbit_cameras(size, size)
        best: dict[str, float] = {}
        for _ in range(reps):
            out = native.forward(
                *arrays(scene), viewmats.numpy(), ks.numpy(), size, size, threads=1
            )
            for k, v in out["profile"].items():
                best[k] = min(best.get(k, float("inf")), v)
        total = sum(best.values())
        cells = " | ".join(
            f"{best[k] * 1e3:.1f} ({best[k] / total:.0%})"
            for k in ("project", "sort", "bin", "blend")
        )
        rows.append(f"| {n:,} @ {size}^2 | {cells} |")
        blend_share[(n, size)] = best["blend"] / total
        print(rows[-1], flush=True)
    return (
        "| scene | projection (ms) | depth sort + SH | tile binning | blending |\n"
        "|---|---|---|---|---|\n" + "\n".join(rows)
    ), blend_share


def vm_kib(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field):
            return int(line.split()[1])
    return -1


def train_step_table(reps: int) -> tuple[str, list[dict]]:
    rows, data = [], []
    for size in (512, 768):
        scene = synthetic_plant(100_000)
        viewmats, ks = orbit_cameras(size, size)
        bg = torch.full((1, 3), 0.75)
        best_f = best_b = float("inf")
        peak = -1
        for rep in range(reps):
            params = [x.clone().requires_grad_(True) for x in scene]
            base = vm_kib("VmRSS")
            try:  # reset the peak-RSS counter (Linux)
                Path("/proc/self/clear_refs").write_text("5")
            except OSError:
                pass
            t0 = time.perf_counter()
            img, alpha, _ = rasterization(
                *params, viewmats, ks, size, size, backgrounds=bg, threads=2
            )
            loss = (img - 0.5).square().mean() + alpha.mean()
            t1 = time.perf_counter()
            loss.backward()
            t2 = time.perf_counter()
            if rep == 0:
                peak = vm_kib("VmHWM") - base
            best_f, best_b = min(best_f, t1 - t0), min(best_b, t2 - t1)
        out = native.forward(*arrays(scene), viewmats.numpy(), ks.numpy(), size, size, threads=2)
        state_mib = out["state"].nbytes / 2**20
        rows.append(
            f"| 100,000 @ {size}^2 | {best_f * 1e3:.1f} | {best_b * 1e3:.1f} | "
            f"{best_b / best_f:.2f} | {state_mib:.1f} | {peak / 1024:.0f} |"
        )
        data.append(
            {
                "size": size,
                "forward_ms": best_f * 1e3,
                "backward_ms": best_b * 1e3,
                "state_mib": state_mib,
                "peak_mib": peak / 1024,
            }
        )
        print(rows[-1], flush=True)
    return (
        "| scene | forward (ms) | backward (ms) | backward / forward | saved forward state (MiB) "
        "| peak RSS growth of the step (MiB) |\n|---|---|---|---|---|---|\n" + "\n".join(rows)
    ), data


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="fewer sizes and repetitions")
    args = parser.parse_args()
    reps = 2 if args.quick else 30
    counts = (10_000, 100_000) if args.quick else (10_000, 100_000, 1_000_000)
    sizes = (256, 512) if args.quick else (256, 512, 768)

    fwd, fwd_data = forward_table(reps, sizes, counts)
    knobs, knob_data = knob_table(reps // 2, err_size=160, err_n=6000)
    prof, blend_share = profile_table(reps // 2)
    step, step_data = train_step_table(max(2, reps // 2))

    at = {(d["n"], d["size"]): d["ms_2_threads"] for d in fwd_data}
    med = {(d["n"], d["size"]): d["median_ms_2_threads"] for d in fwd_data}
    ratio = max(d["backward_ms"] / d["forward_ms"] for d in step_data)
    f512, f768 = at.get((100_000, 512)), at.get((100_000, 768))
    shares = [blend_share[k] for k in ((100_000, 512), (100_000, 768)) if k in blend_share]
    verdict = (
        f"Targets: backward <= 2x forward is {'met' if ratio <= 2 else 'NOT met'} "
        f"(worst ratio {ratio:.2f}). Forward, 100k on 2 threads: "
        + (
            f"{f512:.1f} ms at 512^2 (median {med[(100_000, 512)]:.1f}; target 25, "
            f"{'met' if f512 <= 25 else '**not met**'}), "
            if f512
            else ""
        )
        + (
            f"{f768:.1f} ms at 768^2 (median {med[(100_000, 768)]:.1f}; target 50, "
            f"{'met' if f768 <= 50 else '**not met**'}). "
            if f768
            else ""
        )
        + (
            f"Blending is {min(shares):.0%}-{max(shares):.0%} of the 1-thread time at 100k "
            f"({_core.info()['blend_kernel']} kernel); projection and tile binning most of the "
            "rest."
            if shares
            else ""
        )
    )
    md = f"""## Rasterizer (`plantdreamer.rasterization`)

Command: `{COMMAND}`. Scene: `benches/raster_scene.py`, a synthetic plant (longest side 4,
stem + 40 leaves, Gaussians on the surfaces with kNN-like sizes, flattened along the normal,
opacities spread over (0.05, 1)), one orbit camera at distance 4.5, elevation 15, fovy 55.
Blending kernel: `{_core.info()["blend_kernel"]}` (`plantdreamer info`).

**How to read the times.** The machine is a 2-vCPU VM whose CPU time the host caps: with
nothing else running in the VM, a fixed pure-Python loop takes ~10 ms in some seconds and
~19 ms in others, on either vCPU (see the line under the forward table), and sustained
load makes the slow spells more frequent. So the forward table gives the minimum (the
code at the machine's full speed) and the median over {reps} calls per row, spread over
{ROUNDS} rounds through all sizes (in a shuffled order, after a 0.2 s rest), each block
after one untimed warm-up call
({max(2, reps // 3)} calls in one round for 1M Gaussians); the other tables give minima
over {reps // 2} calls.

### Forward time

{fwd}

Machine speed during this table: a fixed pure-Python loop, timed before every block of
calls, took {min(CALIBRATION):.1f} ms at best and {float(np.median(CALIBRATION)):.1f} ms at
the median (median / min = {float(np.median(CALIBRATION)) / min(CALIBRATION):.2f}), the
same kind of spread as the rasterizer's min and median.

Targets (issue 4): 100k at 512^2 <= 25 ms and at 768^2 <= 50 ms on 2 threads.

### Time against error

Time on the 100k scene at 512^2 (2 threads); error = absolute per-pixel error of RGB and
alpha against the dense float64 reference (`tests/raster_reference.py`) on a 6k-Gaussian
version of the scene at 160^2 (the reference is O(N x pixels)).

{knobs}

Defaults: the opacity-aware footprint (the exact box of the alpha = 1/255 contour: it
loses nothing against the reference, unlike 3 sigma, whose cut tails give errors up to
~2e-2), the tile-ellipse test (identical image, ~20% fewer intersections), 32-pixel tiles
and T_min = 1e-4. Except for the tile size (gsplat's is 16, which a CPU pays for in
intersections), these are gsplat's semantics, which the rest of plantdreamer and the
reference assume; every row that changes the image (3 sigma, another T_min, including
T_min = 0, i.e. no early stop) is measured against that reference, hence its error. With
the default footprint, tile size and the ellipse test never change the image
(bit-identical, tested), only the time;
the scalar row is the same image computed without SIMD (bit-identical, tested). The
errors of the default row include the blending exp, a polynomial accurate to 2 ulp
(`forward::exp_neg`) that forward, backward, SIMD and scalar kernels share.

### Where the time goes (1 thread)

{prof}

Projection runs eight Gaussians at a time; the colour / SH features (and the blend's
per-splat records) are computed beside the depth sort, which runs on one thread, so that
column holds both. Blending includes gathering each tile's splats and features from its
list and writing the tile's rows of the image. Per-kernel detail without Python:
`python benches/raster_scene.py --dump /tmp/scene.bin` then
`cargo run --release -p splat_core --example raster_timing -- /tmp/scene.bin 1` (under
`perf record` for a profile).

### Training step (forward + backward through torch autograd, 2 threads)

{step}

The saved forward state (`RasterState.nbytes`: input copy, splats and features, tile
lists, final T and last index per pixel) is O(N + pixels + intersections); nothing
per (pixel, Gaussian) pair is stored (see `crates/splat_core/src/raster/mod.rs`). The RSS
growth is measured with /proc (VmHWM after a reset); it under-counts memory the allocator
had already cached from earlier runs in the same process.

{verdict}
"""
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "raster.md").write_text(md)
    (RESULTS / "raster.json").write_text(
        json.dumps({"forward": fwd_data, "knobs": knob_data, "train_step": step_data}, indent=1)
    )
    print(md)


if __name__ == "__main__":
    main()
