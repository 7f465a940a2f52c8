"""Measures the figures of docs/fidelity.md: depth-rule saturation and depth order, and the
share of Gaussians culled per run for C = 3 and C = 7.

    .venv/bin/python scripts/fidelity_figures.py [--cameras 16] [--out docs/fidelity_figures.md]

Scenes: the three L-System species (seed 1, 100k mesh samples) and two real-style clouds,
made here from L-System plants (bean seed 7, mint seed 5: 300k samples, Gaussian jitter of
0.3% of the plant size, 3% uniform outliers in the bounding box) and prepared like a capture
(SOR, voxel grid to 100k points, normalised).

Depth: the initial Gaussians are rendered (expected depth and alpha, 512 px) from
``--cameras`` training cameras of the default sampler; each rule's ``normalise_depth`` (before
erosion) is compared over plant pixels (alpha > 0.5): the share set to 1.0 (saturated), the
share dropped to 0, and Spearman's rank correlation of the normalised value with -depth
(1 = nearer is always brighter).

Culling: the culling rounds of a 3600-step ``--guidance none`` run (ours: steps 600, 700,
..., 3500; the released rounds 599, ..., 3599 for the released column) replayed on the
initial Gaussians for each C and volume rule. That is what such a run
does: nothing is optimised, so densification selects nothing, no opacity falls below the
prune threshold, and each round cuts the tail of the initial scale distribution. The figure
is the share of the initial Gaussians culled over the run.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
from pathlib import Path

import numpy as np
import torch

from plantdreamer.atomic import write_text
from plantdreamer.cloud import PointCloud
from plantdreamer.guidance.depth import DEPTH_RULES, DepthCleaning, normalise_depth
from plantdreamer.io import write_ply
from plantdreamer.lsystem import generate_plant, sample_points
from plantdreamer.pipeline import GenerateConfig
from plantdreamer.pipeline.model.culling import large_gaussian_mask
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.model.sampler import CameraSampler
from plantdreamer.pipeline.model.source import initial_gaussians, load_source
from plantdreamer.pipeline.settings.presets import PRESETS

SPECIES = ("bean", "mint", "kale")
REAL_STYLE = (("bean", 7), ("mint", 5))


def real_style_cloud(species: str, seed: int, path: Path) -> Path:
    """A noisy, outlier-laden cloud from an L-System plant, written as a PLY."""
    rng = np.random.default_rng(seed)
    cloud = sample_points(generate_plant(species, seed), n=300_000, seed=seed)
    pts = cloud.positions.astype(np.float64)
    size = float(np.ptp(pts, axis=0).max())
    pts = pts + rng.normal(scale=0.003 * size, size=pts.shape)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    outliers = rng.uniform(lo, hi, size=(int(0.03 * len(pts)), 3))
    colors = np.concatenate([cloud.colors, rng.random((len(outliers), 3))])
    write_ply(
        path,
        PointCloud(np.concatenate([pts, outliers]).astype(np.float32), colors.astype(np.float32)),
    )
    return path


def scenes(tmp: Path) -> dict[str, dict]:
    """Name -> GenerateConfig options of each scene."""
    out = {s: {"species": s, "seed": 1} for s in SPECIES}
    for species, seed in REAL_STYLE:
        ply = real_style_cloud(species, seed, tmp / f"{species}{seed}.ply")
        out[f"{species} {seed} (real-style)"] = {"species": species, "pointcloud": str(ply)}
    return out


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation, ties ranked by their mean rank."""

    def ranks(x: np.ndarray) -> np.ndarray:
        _, inverse, counts = np.unique(x, return_inverse=True, return_counts=True)
        ends = np.cumsum(counts)
        return ((ends - (counts - 1) / 2.0) - 1.0)[inverse]

    ra, rb = ranks(a), ranks(b)
    if ra.std() == 0 or rb.std() == 0:
        return float("nan")
    return float(np.corrcoef(ra, rb)[0, 1])


def initial_model(options: dict) -> tuple[GaussianModel, GenerateConfig]:
    """The initial Gaussians of a run with these options (default settings otherwise)."""
    cfg = GenerateConfig.of(**options)
    source = load_source(cfg.source, cfg.seed, surface=cfg.init.init_shape == "surface")
    return GaussianModel(initial_gaussians(cfg.init, source, cfg.seed)), cfg


def depth_figures(model: GaussianModel, cfg: GenerateConfig, n_cameras: int) -> dict:
    sampler = CameraSampler(cfg.train.cameras, 512, cfg.seed)
    per_rule: dict[str, dict[str, list]] = {
        r: {"sat": [], "drop": [], "rho": []} for r in DEPTH_RULES
    }
    for _ in range(n_cameras):
        camera = sampler.sample()
        with torch.no_grad():
            depth, alpha, _ = model.render([camera], 0.75, "ED")
        d, a = depth[0, ..., 0], alpha[0, ..., 0]
        plant = (a > 0.5).numpy()
        if plant.sum() < 100:
            continue
        true_depth = d.numpy()[plant]
        for rule in DEPTH_RULES:
            n = normalise_depth(d, a, DepthCleaning(rule=rule)).numpy()[plant]
            per_rule[rule]["sat"].append(float(np.mean(n >= 1.0)))
            per_rule[rule]["drop"].append(float(np.mean(n <= 0.0)))
            per_rule[rule]["rho"].append(spearman(n, -true_depth))
    return {
        rule: {
            "saturated_mean": float(np.mean(v["sat"])),
            "saturated_min": float(np.min(v["sat"])),
            "saturated_max": float(np.max(v["sat"])),
            "dropped_mean": float(np.mean(v["drop"])),
            "spearman_mean": float(np.nanmean(v["rho"])),
            "spearman_min": float(np.nanmin(v["rho"])),
            "views": len(v["sat"]),
        }
        for rule, v in per_rule.items()
    }


def cull_figures(log_scales: torch.Tensor, cfg: GenerateConfig) -> dict[str, float]:
    released = dataclasses.replace(cfg.density.cull, offset=PRESETS["released"]["cull-offset"])
    rounds = {
        cull.offset: sum(cull.due(s) for s in range(cfg.train.steps))
        for cull in (cfg.density.cull, released)
    }
    settings = [(3.0, "log", 0), (7.0, "log", 0), (3.0, "double-exp", 0), (7.0, "double-exp", 0)]
    settings.append((7.0, "double-exp", released.offset))
    out = {}
    for c, volume, offset in settings:
        kept = log_scales
        for _ in range(rounds[offset]):
            mask, _ = large_gaussian_mask(kept, c, volume)
            kept = kept[~mask]
        name = f"C={c:g} {volume}" + (f", {rounds[offset]} rounds (released)" if offset else "")
        out[name] = 1.0 - len(kept) / len(log_scales)
    return out


def markdown(depth: dict, cull: dict, n_cameras: int) -> str:
    lines = [
        "# Fidelity figures",
        "",
        "Made by `scripts/fidelity_figures.py` (see its docstring for the scenes and method).",
        "",
        f"## Depth normalisation ({n_cameras} training cameras per scene, plant pixels)",
        "",
        "| scene | rule | saturated (mean, min-max) | dropped | Spearman (mean, min) |",
        "|---|---|---|---|---|",
    ]
    for scene, rules in depth.items():
        for rule, f in rules.items():
            lines.append(
                f"| {scene} | {rule} | {100 * f['saturated_mean']:.1f}% "
                f"({100 * f['saturated_min']:.1f}-{100 * f['saturated_max']:.1f}%) | "
                f"{100 * f['dropped_mean']:.1f}% | {f['spearman_mean']:.3f} "
                f"({f['spearman_min']:.3f}) |"
            )
    settings = list(next(iter(cull.values())))
    lines += [
        "",
        "## Share of the initial Gaussians culled over a run (the rounds of a 3600-step "
        "`--guidance none` run)",
        "",
        "| scene | " + " | ".join(settings) + " |",
        "|---|" + "---|" * len(settings),
    ]
    for scene, f in cull.items():
        lines.append(f"| {scene} | " + " | ".join(f"{100 * f[s]:.3f}%" for s in settings) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cameras", type=int, default=16)
    parser.add_argument("--out", type=Path, default=Path("docs/fidelity_figures.md"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp_dir:
        depth, cull = {}, {}
        for name, options in scenes(Path(tmp_dir)).items():
            model, cfg = initial_model(options)
            print(f"{name}: {len(model)} Gaussians", flush=True)
            cull[name] = cull_figures(model.params["log_scales"].detach(), cfg)
            depth[name] = depth_figures(model, cfg, args.cameras)
            print(json.dumps({"depth": depth[name], "cull": cull[name]}), flush=True)
    write_text(args.out, markdown(depth, cull, args.cameras))
    write_text(args.out.with_suffix(".json"), json.dumps({"depth": depth, "cull": cull}, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
