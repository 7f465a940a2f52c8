"""Cost of the ground truth per view (class + instance + depth maps) against the RGB render.

L-System bean and mint (seed 0, 100k points, as `generate` initialises them), 512x512, 8 views of the
evaluation orbit. Per view, interleaved ``REPEATS`` times: the RGB render as the evaluation
renders make it, the ground truth as `generate` then makes it (one `GroundTruthRenderer` for
all views, given each render's footprints: classes, instance channels shared between leaves
whose tiles do not meet, and depth, in one pass), and, for reference, one one-hot channel
per instance in a single pass (what the channel sharing avoids). Minimum and median over
all views and repeats.

    python benches/bench_labels.py
    python benches/bench_labels.py --baseline OLD.py  # also an older ground_truth.py

``--baseline``: a ground_truth.py of another version (e.g. ``git show
REV:python/plantdreamer/pipeline/ground_truth.py > OLD.py``), timed interleaved with the
rest on the same models; its maps must equal this version's.
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
VIEWS = 8
REPEATS = 3


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def load_baseline(path: str):
    import importlib.util

    spec = importlib.util.spec_from_file_location("baseline_ground_truth", path)
    assert spec is not None and spec.loader is not None, path
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def measure(species: str, baseline=None) -> dict[str, float | tuple[float, float]]:
    import numpy as np
    import torch

    from plantdreamer.cameras import orbit_ring
    from plantdreamer.pipeline import GenerateConfig
    from plantdreamer.pipeline.model.gaussian_model import GaussianModel
    from plantdreamer.pipeline.model.source import initial_gaussians, load_source
    from plantdreamer.pipeline.truth.ground_truth import (
        GroundTruthRenderer,
        LabelSet,
        Splats,
        _blend,
    )
    from plantdreamer.pipeline.truth.label_channels import one_hot, share_channels

    cfg = GenerateConfig.of(species=species, seed=0, points=100_000)
    source = load_source(cfg.source, cfg.seed, surface=cfg.init.init_shape == "surface")
    g = initial_gaussians(cfg.init, source, cfg.seed)  # the Gaussians generate starts from
    model, ls = GaussianModel(g), LabelSet.of(g.labels)
    times: dict[str, list[float]] = {"rgb": [], "gt": [], "naive": []}
    if baseline is not None:
        times["baseline"], old_ls = [], baseline.LabelSet.of(g.labels)
    channels = []
    all_instances = one_hot(ls.instance_channel, 0, len(ls.instances) + 1)
    with torch.no_grad():
        ground_truth, splats = GroundTruthRenderer(model, ls), Splats.of(model)
        for cam in orbit_ring(VIEWS, 4.0, 15.0, 70.0, 512, 512):
            meta = model.render([cam], 0.75)[2]
            channels.append(int(share_channels(ls, meta, cam)[0].max()) + 1)
            for _ in range(REPEATS):
                times["rgb"].append(timed(lambda cam=cam: model.render([cam], 0.75)))
                times["gt"].append(timed(lambda cam=cam, meta=meta: ground_truth(cam, meta)))
                times["naive"].append(
                    timed(lambda cam=cam: _blend(splats, cam, all_instances, False))
                )
                if baseline is not None:
                    times["baseline"].append(
                        timed(
                            lambda cam=cam, meta=meta: baseline.render_ground_truth(
                                model, cam, old_ls, meta
                            )
                        )
                    )
            if baseline is not None:
                new, old = (
                    ground_truth(cam, meta),
                    baseline.render_ground_truth(model, cam, old_ls, meta),
                )
                for field in ("label", "instance", "depth", "alpha"):
                    assert np.array_equal(getattr(new, field), getattr(old, field)), field
    return {
        "instances": len(ls.instances),
        "channels": statistics.median(channels),
        **{k: (min(v), statistics.median(v)) for k, v in times.items()},
    }


def main() -> int:
    import argparse

    import torch

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", help="an older ground_truth.py to time alongside")
    args = parser.parse_args()
    baseline = load_baseline(args.baseline) if args.baseline else None
    load_before = os.getloadavg()[0]
    rows = [(s, measure(s, baseline)) for s in ("bean", "mint")]
    load = f"{load_before:.1f} before, {os.getloadavg()[0]:.1f} after"
    command = "python benches/run_all.py labels"
    if args.baseline:
        command = f"python benches/bench_labels.py --baseline {Path(args.baseline).name}"
    lines = [
        "## Ground-truth masks (`benches/bench_labels.py`)\n",
        f"Command: `{command}`. L-System plants, seed 0, 100k Gaussians",
        f"as initialised, 512x512, {VIEWS} views of the evaluation orbit, {REPEATS} interleaved",
        "repeats per view, min / median over views and repeats, milliseconds, CPU, "
        f"{torch.get_num_threads()} torch threads. *ground truth* is classes + instances +",
        "depth as `generate` makes them after each render (before PNG encoding); *one channel per instance* is",
        "a single pass with one one-hot channel per leaf, the cost that the shared channels",
        "avoid. The aim is a ground truth at most 1.5x the RGB render. Measured on a shared",
        f"2-core machine, 1-minute load average {load}: the minima are noisy, the medians",
        "steadier.\n",
        "| plant | leaves | instance channels (median) | RGB render | ground truth "
        "| ratio (min / median) | one channel per instance (instances only) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in rows:
        rgb, gt, naive = r["rgb"], r["gt"], r["naive"]
        lines.append(
            f"| {name} | {r['instances']} | {r['channels']:.0f} "
            f"| {1000 * rgb[0]:.0f} / {1000 * rgb[1]:.0f} | {1000 * gt[0]:.0f} / {1000 * gt[1]:.0f} "
            f"| {gt[0] / rgb[0]:.2f}x / {gt[1] / rgb[1]:.2f}x "
            f"| {1000 * naive[0]:.0f} / {1000 * naive[1]:.0f} |"
        )
    if baseline is not None:
        lines += ["", f"Baseline `{Path(args.baseline).name}`, timed interleaved (same maps):", ""]
        lines += ["| plant | baseline ground truth | ratio (min / median) |", "|---|---|---|"]
        for name, r in rows:
            rgb, old = r["rgb"], r["baseline"]
            lines.append(
                f"| {name} | {1000 * old[0]:.0f} / {1000 * old[1]:.0f} "
                f"| {old[0] / rgb[0]:.2f}x / {old[1] / rgb[1]:.2f}x |"
            )
    lines.append("")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "labels.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
