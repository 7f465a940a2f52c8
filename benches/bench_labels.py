"""Cost of the ground truth per view (class + instance + depth maps) against the RGB render.

L-System bean and mint (seed 0, 100k points, as initialised), 512x512, 8 views of the
evaluation orbit. Per view: the RGB render as the evaluation renders make it, and the ground
truth as `generate` then makes it (`render_ground_truth` given the render's footprints:
classes, instance channels shared between leaves whose tiles do not meet, and depth, in one
pass), and, for reference, one one-hot channel per instance in a single pass (what the
channel sharing avoids).

    python benches/bench_labels.py
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
VIEWS = 8
REPEATS = 3


def best_of(fn) -> float:
    times = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def measure(species: str) -> dict[str, float]:
    import numpy as np
    import torch

    from plantdreamer.cameras import orbit_ring
    from plantdreamer.lsystem import generate_plant, sample_points
    from plantdreamer.pipeline.ground_truth import (
        LabelSet,
        _blend,
        _one_hot,
        _share_channels,
        render_ground_truth,
    )
    from plantdreamer.pipeline.init import init_gaussians
    from plantdreamer.pipeline.model import GaussianModel
    from plantdreamer.pointcloud import normalize

    cloud = sample_points(generate_plant(species, 0), n=100_000, seed=0)
    points, _ = normalize(cloud.positions, 4.0)
    labels = np.stack([cloud.attributes["label"], cloud.attributes["instance"]], axis=1)
    g = init_gaussians(points.astype(np.float32), cloud.colors, 0.7, labels=labels)
    model, ls = GaussianModel(g), LabelSet.of(g.labels)
    rgb, gt, naive, channels = [], [], [], []
    all_instances = _one_hot(ls.instance_channel, 0, len(ls.instances) + 1)
    with torch.no_grad():
        for cam in orbit_ring(VIEWS, 4.0, 15.0, 70.0, 512, 512):
            rgb.append(best_of(lambda cam=cam: model.render([cam], 0.75)))
            meta = model.render([cam], 0.75)[2]
            gt.append(best_of(lambda cam=cam, meta=meta: render_ground_truth(model, cam, ls, meta)))
            naive.append(best_of(lambda cam=cam: _blend(model, cam, all_instances, False)))
            channels.append(int(_share_channels(ls, meta, cam)[0].max()) + 1)
    return {
        "instances": len(ls.instances),
        "channels": statistics.median(channels),
        "rgb": statistics.median(rgb),
        "gt": statistics.median(gt),
        "naive": statistics.median(naive),
    }


def main() -> int:
    import torch

    rows = [(s, measure(s)) for s in ("bean", "mint")]
    lines = [
        "## Ground-truth masks (`benches/bench_labels.py`)\n",
        "Command: `python benches/run_all.py labels`. L-System plants, seed 0, 100k Gaussians",
        f"as initialised, 512x512, {VIEWS} views of the evaluation orbit, best of {REPEATS} per",
        "view, median over views, milliseconds, CPU, "
        f"{torch.get_num_threads()} torch threads. *ground truth* is classes + instances +",
        "depth as `generate` makes them after each render (before PNG encoding); *one channel per instance* is",
        "a single pass with one one-hot channel per leaf, the cost that the shared channels",
        "avoid. The aim is a ground truth at most 1.5x the RGB render. Measured on a shared,",
        "loaded 2-core machine: ratios are noisy.\n",
        "| plant | leaves | instance channels (median) | RGB render | ground truth | ratio "
        "| one channel per instance (instances only) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in rows:
        lines.append(
            f"| {name} | {r['instances']} | {r['channels']:.0f} | {1000 * r['rgb']:.0f} "
            f"| {1000 * r['gt']:.0f} | {r['gt'] / r['rgb']:.2f}x | {1000 * r['naive']:.0f} |"
        )
    lines.append("")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "labels.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
