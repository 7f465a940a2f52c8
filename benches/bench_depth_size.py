"""The ControlNet's depth map made at the SDS size against made at the render size and
resized (``--depth-size sds`` / ``render``): the cost of each, and how far apart the maps are.

    python benches/bench_depth_size.py [--species bean mint kale] [--views 24]

Writes benches/results/depth_size.md (and .json beside it). For each plant (the pipeline's
own initial Gaussians, 100k at the defaults) and each of ``--views`` training cameras
(the run's own sampler), both routes run through ``DepthConditioner``, interleaved:
``render`` renders the initial Gaussians at ``--render`` and cleans there, then resizes to
``--sds`` (bilinear with antialiasing, the default ``--control-resize``); ``sds`` renders
and cleans at ``--sds``. Time is process CPU time per map (render and cleaning; the
rasterizer uses every core). The maps are compared on the conditioning image the
ControlNet reads: mean and 99th-percentile absolute difference, the share of pixels apart
by more than one 8-bit level and by more than 0.1, and the IoU of the plant's pixels
(value above 0). As a yardstick, the same figures for the released code's nearest resize
against the bilinear one (both at the render size).

Then the depth render alone (no cleaning) at the SDS size with each of ``--tiles`` tile
sizes, interleaved, and whether they give the same bits (the depth maps render with the
rasterizer's default tile size).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import torch

from plantdreamer.pipeline.model.gaussian_model import GaussianModel, camera_args
from plantdreamer.pipeline.model.render import FrozenScene
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pipeline.settings.runtime import resolve_plants
from plantdreamer.pipeline.state.run_state import RunState
from plantdreamer.rasterizer import RASTER_DEFAULTS, rasterization

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host import host_line

RESULTS = Path(__file__).resolve().parent / "results"
TILE = RASTER_DEFAULTS["tile_size"]
ROUTES = ("render", "sds")


def conditioners(cfg: GenerateConfig, scene: FrozenScene) -> dict[str, Any]:
    """One ``DepthConditioner`` per route over ``scene`` (no cache: every map is made)."""
    from plantdreamer.guidance.depth import DepthCleaning, DepthConditioner

    sds = cfg.sds
    cleaning = DepthCleaning(
        rule=sds.depth_rule, resize=sds.control_resize, distance=sds.erosion_distance
    )

    def render_depth(camera):
        depth, alpha, _ = scene.render([camera], cfg.train.background)
        return depth, alpha

    made = {
        route: DepthConditioner(
            render_depth, cache_size=0, out_size=sds.resolution, config=cleaning, depth_size=route
        )
        for route in ROUTES
    }
    # The yardstick: the released code's nearest resize against the bilinear one.
    made["nearest"] = DepthConditioner(
        render_depth, cache_size=0, out_size=sds.resolution, config=cleaning,
        depth_size="render", resize="nearest",
    )  # fmt: skip
    return made


def differences(a: torch.Tensor, b: torch.Tensor) -> dict[str, float]:
    diff = (a - b).abs().reshape(-1).double()
    inside_a, inside_b = a > 0, b > 0
    union = int((inside_a | inside_b).sum())
    return {
        "mean_abs": float(diff.mean()),
        "p99_abs": float(torch.quantile(diff, 0.99)),
        "over_one_level": float((diff > 1.0 / 255.0).double().mean()),
        "over_0.1": float((diff > 0.1).double().mean()),
        "plant_iou": 1.0 if union == 0 else int((inside_a & inside_b).sum()) / union,
    }


def measure(species: str, args: argparse.Namespace) -> dict[str, Any]:
    cfg = GenerateConfig.of(
        species=species, seed=0, steps=args.views, points=args.points,
        resolution=args.render, sds_resolution=args.sds, device="cpu",
    )  # fmt: skip
    resolve_plants([cfg])
    state = RunState.fresh(cfg, show_progress=False)
    scene = FrozenScene(GaussianModel(state.initial), "ED")  # as the trainer renders maps
    routes = conditioners(cfg, scene)
    cameras = [state.sampler.sample() for _ in range(args.views)]
    times: dict[str, list[float]] = {r: [] for r in ROUTES}
    rows, nearest = [], []
    routes["sds"]([cameras[0]]), routes["render"]([cameras[0]])  # warm-up
    for i, camera in enumerate(cameras):
        maps = {}
        for route in ROUTES if i % 2 == 0 else ROUTES[::-1]:  # interleaved
            t0 = time.process_time()
            maps[route] = routes[route]([camera])
            times[route].append(1000 * (time.process_time() - t0))
        rows.append(differences(maps["sds"], maps["render"]))
        nearest.append(differences(routes["nearest"]([camera]), maps["render"]))
    return {
        "species": species,
        "core_ms": {r: {"min": min(t), "median": statistics.median(t)} for r, t in times.items()},
        "difference": {k: statistics.mean(r[k] for r in rows) for k in rows[0]},
        "worst_mean_abs": max(r["mean_abs"] for r in rows),
        "worst_plant_iou": min(r["plant_iou"] for r in rows),
        "nearest_difference": {k: statistics.mean(r[k] for r in nearest) for k in nearest[0]},
        "tiles": tile_sizes(scene, cameras, cfg, args),
    }


def tile_sizes(scene: FrozenScene, cameras: list, cfg: GenerateConfig, args) -> dict[str, Any]:
    """Core-ms of the depth render alone at the SDS size per tile size (min / median over
    the cameras, interleaved), and whether every tile size gave the first one's bits."""
    times: dict[int, list[float]] = {t: [] for t in args.tiles}
    same = True
    for i, camera in enumerate(cameras):
        call = camera_args([camera.resized(args.sds, args.sds)], cfg.train.background, "ED")
        bits = {}
        for tile in args.tiles if i % 2 == 0 else args.tiles[::-1]:
            t0 = time.process_time()
            with torch.no_grad():
                depth, alpha, _ = rasterization(**scene.scene, **call, tile_size=tile)
            times[tile].append(1000 * (time.process_time() - t0))
            bits[tile] = depth.numpy().tobytes() + alpha.numpy().tobytes()
        same &= len(set(bits.values())) == 1
    return {
        "core_ms": {t: {"min": min(v), "median": statistics.median(v)} for t, v in times.items()},
        "same_bits": same,
    }


def markdown(report: dict[str, Any]) -> str:
    a = report["args"]
    lines = [
        "## Depth conditioning at the SDS size against the render size "
        "(`benches/bench_depth_size.py`)",
        "",
        f"Command: `{report['command']}`; {report['host']}, torch threads "
        f"{report['torch_threads']}. {a['points']} points per plant, render {a['render']} px, "
        f"SDS {a['sds']} px, {a['views']} training cameras per plant. Core-ms: process CPU "
        "time per map (render and cleaning), min / median. Differences: on the "
        "[0, 1] conditioning image, means over the views (worst view in brackets), of the "
        "SDS-size map against the render-size one; the yardstick row under each plant "
        "compares the released code's nearest resize with the bilinear one instead.",
        "",
        "| plant | core-ms, render size then resize | core-ms, SDS size | mean abs | "
        "p99 abs | pixels > 1/255 | pixels > 0.1 | plant IoU |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in report["plants"]:
        t, d = r["core_ms"], r["difference"]
        lines.append(
            f"| {r['species']} | {t['render']['min']:.1f} / {t['render']['median']:.1f} | "
            f"{t['sds']['min']:.1f} / {t['sds']['median']:.1f} | {d['mean_abs']:.4f} "
            f"({r['worst_mean_abs']:.4f}) | {d['p99_abs']:.3f} | "
            f"{100 * d['over_one_level']:.2f}% | {100 * d['over_0.1']:.2f}% | "
            f"{d['plant_iou']:.4f} ({r['worst_plant_iou']:.4f}) |"
        )
        n = r["nearest_difference"]
        lines.append(
            f"| {r['species']}: nearest vs bilinear resize | | | {n['mean_abs']:.4f} | "
            f"{n['p99_abs']:.3f} | {100 * n['over_one_level']:.2f}% | "
            f"{100 * n['over_0.1']:.2f}% | {n['plant_iou']:.4f} |"
        )
    tiles = a["tiles"]
    lines += [
        "",
        f"The depth render alone at {a['sds']} px (no cleaning), per tile size, core-ms min / "
        f"median over the same cameras, interleaved; the depth maps render with the "
        f"default {TILE} px tiles:",
        "",
        "| plant | " + " | ".join(f"tile {t} px" for t in tiles) + " | same bits |",
        "|---|" + "---:|" * len(tiles) + "---|",
    ]
    for r in report["plants"]:
        t = r["tiles"]["core_ms"]
        cells = " | ".join(f"{t[k]['min']:.1f} / {t[k]['median']:.1f}" for k in tiles)
        lines.append(f"| {r['species']} | {cells} | {'yes' if r['tiles']['same_bits'] else 'NO'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--species", nargs="+", default=["bean", "mint", "kale"])
    p.add_argument("--views", type=int, default=24)
    p.add_argument("--points", type=int, default=100_000)
    p.add_argument("--render", type=int, default=768)
    p.add_argument("--sds", type=int, default=512)
    p.add_argument("--tiles", type=int, nargs="+", default=sorted({8, 16, TILE}),
                   help="tile sizes of the depth render compared")  # fmt: skip
    p.add_argument("--torch-threads", type=int, default=1, help="as a run's default")
    p.add_argument("--out", type=Path, default=RESULTS / "depth_size.md")
    args = p.parse_args(argv)
    torch.set_num_threads(args.torch_threads)
    report = {
        "command": "python benches/bench_depth_size.py " + " ".join(sys.argv[1:]),
        "host": host_line(),
        "torch_threads": args.torch_threads,
        "args": vars(args) | {"out": str(args.out)},
        "plants": [measure(s, args) for s in args.species],
    }
    text = markdown(report)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    args.out.with_suffix(".json").write_text(json.dumps(report, indent=2) + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
