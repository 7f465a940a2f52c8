"""Initial Gaussians from a point cloud (released code's rules) and colour-init ablations."""

from __future__ import annotations

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.gaussians import Gaussians, rgb_to_sh_dc, sh_coeff_count

# Leaf green for clouds without colours (an L-System mesh always has colours).
DEFAULT_RGB = (0.25, 0.45, 0.15)


def initial_colors(
    colors: np.ndarray | None, n: int, mode: str, rng: np.random.Generator
) -> np.ndarray:
    """Colours for the paper's colour-init ablation: original, noise, black or white."""
    if mode == "original":
        if colors is None:
            return np.broadcast_to(np.asarray(DEFAULT_RGB, np.float32), (n, 3)).copy()
        return np.clip(colors.astype(np.float32), 0.0, 1.0)
    if mode == "noise":
        return rng.random((n, 3), dtype=np.float32)
    if mode == "black":
        return np.zeros((n, 3), dtype=np.float32)
    if mode == "white":
        return np.ones((n, 3), dtype=np.float32)
    raise InputError(f"unknown colour init {mode!r}: use original, noise, black or white")


def neighbour_spacing(points: np.ndarray, neighbours: int = 3, rule: str = "mean") -> np.ndarray:
    """Per-point distance scale from the ``neighbours`` nearest other points (float32 [N]):
    their mean distance, or with ``rule="rms"`` the root mean square distance (the released
    code's sqrt of the mean squared distance, as in the original 3DGS)."""
    from plantdreamer.pointcloud import knn, knn_mean_distance

    pts = np.ascontiguousarray(points, dtype=np.float32)
    if rule == "mean":
        return knn_mean_distance(pts, k=neighbours)
    if rule == "rms":
        _, dist = knn(pts, neighbours)
        return np.sqrt(np.mean(dist.astype(np.float64) ** 2, axis=1)).astype(np.float32)
    raise InputError(f"unknown initial scale rule {rule!r}: use mean or rms")


def init_gaussians(
    points: np.ndarray,
    colors: np.ndarray,
    opacity: float,
    sh_degree: int = 0,
    neighbours: int = 3,
    scale_rule: str = "mean",
    labels: np.ndarray | None = None,
) -> Gaussians:
    """Isotropic Gaussians at the points: scale = ``neighbour_spacing`` (mean distance to the
    3 nearest neighbours by default).

    Duplicate points have distance 0; their scale is floored at 1% of the median spacing so
    that log-scales stay finite. ``labels`` ([N, 2] int32, per point) become the Gaussians'.
    """
    n = points.shape[0]
    if n <= neighbours:
        raise InputError(f"need more than {neighbours} points to initialise, got {n}")
    if not 0.0 < opacity < 1.0:
        raise InputError(f"initial opacity must be in (0, 1), got {opacity}")
    dist = neighbour_spacing(points, neighbours, scale_rule)
    positive = dist[dist > 0]
    floor = 0.01 * float(np.median(positive)) if positive.size else 1e-4
    scale = np.maximum(dist, floor).astype(np.float32)
    sh = np.zeros((n, sh_coeff_count(sh_degree), 3), dtype=np.float32)
    sh[:, 0] = rgb_to_sh_dc(colors)
    quats = np.zeros((n, 4), dtype=np.float32)
    quats[:, 0] = 1.0
    logit = np.log(opacity / (1.0 - opacity))
    return Gaussians(
        means=np.ascontiguousarray(points, dtype=np.float32),
        quats=quats,
        log_scales=np.repeat(np.log(scale)[:, None], 3, axis=1).astype(np.float32),
        opacity_logits=np.full(n, logit, dtype=np.float32),
        sh=sh,
        labels=None if labels is None else np.ascontiguousarray(labels, dtype=np.int32),
    )
