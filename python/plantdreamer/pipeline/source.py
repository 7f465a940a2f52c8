"""The run's input as a normalised point cloud: an L-System plant or a prepared capture."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantdreamer.pipeline.config import GenerateConfig


@dataclass
class Source:
    points: np.ndarray  # [N, 3] float32, normalised (centred, longest side = scene_size)
    colors: np.ndarray | None  # [N, 3] float32 in [0, 1]
    transform: object  # plantdreamer.pointcloud.NormalizeTransform, restores the input frame
    counts: dict[str, int]  # points after each preparation step, for run.json


def load_source(cfg: GenerateConfig) -> Source:
    from plantdreamer.pointcloud import normalize

    if cfg.pointcloud is not None:
        points, colors, counts = _captured_points(Path(cfg.pointcloud))
        points, colors, counts = _prepare(points, colors, cfg, counts)
    else:
        points, colors, counts = _lsystem_points(cfg)
    normalised, transform = normalize(points, size=cfg.scene_size)
    return Source(normalised.astype(np.float32), colors, transform, counts)


def _lsystem_points(cfg: GenerateConfig):
    from plantdreamer.lsystem import generate_plant, sample_points

    mesh = generate_plant(cfg.species, cfg.seed)
    cloud = sample_points(mesh, n=cfg.n_points, seed=cfg.seed)
    return cloud.positions, cloud.colors, {"sampled": len(cloud)}


def _captured_points(path: Path):
    from plantdreamer.io import read_ply

    cloud = read_ply(path)
    finite = np.isfinite(cloud.positions).all(axis=1)
    if not finite.all():
        cloud = cloud.subset(finite)
    return cloud.positions, cloud.colors, {"read": int(finite.size), "finite": int(finite.sum())}


def _prepare(points, colors, cfg: GenerateConfig, counts: dict[str, int]):
    """SOR then voxel downsampling to about ``n_points`` (paper Sec. 3.4)."""
    from plantdreamer.pointcloud import downsample_to_count, remove_statistical_outliers

    if len(points) > cfg.sor_neighbors:
        kept = remove_statistical_outliers(points, cfg.sor_neighbors, cfg.sor_std)
        points = points[kept]
        colors = None if colors is None else colors[kept]
        counts["after_sor"] = len(points)
    if len(points) > cfg.n_points:
        points, colors, _ = downsample_to_count(points, cfg.n_points, colors=colors)
        counts["after_voxel"] = len(points)
    return points, colors, counts
