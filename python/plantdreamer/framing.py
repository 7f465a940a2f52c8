"""Framing any 3DGS scene for the orbit: a robust centre and size, and which axis is up.

Models from other tools carry stray Gaussians far from the subject (floaters, background
splats). A bounding box follows them, so the subject shrinks to a few pixels. Here the
centre is the opacity-weighted median of the means and the size is the longest side of the
opacity-weighted central 96% (2% trimmed on each side of every axis): a handful of far
Gaussians moves neither. Captured scenes are often y-down; ``up`` rotates the named axis
onto +z, the orbit's up.
"""

from __future__ import annotations

import math

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.gaussians import Gaussians
from plantdreamer.pointcloud import NormalizeTransform

__all__ = ["TRIM", "UP_AXES", "robust_center_extent", "rotate_up", "to_scene_frame"]

TRIM = 0.02  # weight trimmed on each side of every axis when measuring the size

_H = math.sqrt(0.5)
# up axis -> (rotation taking it to +z, the same rotation as a (w, x, y, z) quaternion)
UP_AXES: dict[str, tuple[np.ndarray, tuple[float, float, float, float]]] = {
    "z": (np.eye(3), (1.0, 0.0, 0.0, 0.0)),
    "-z": (np.diag([1.0, -1.0, -1.0]), (0.0, 1.0, 0.0, 0.0)),
    "y": (np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), (_H, _H, 0.0, 0.0)),
    "-y": (np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]), (_H, -_H, 0.0, 0.0)),
    "x": (np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]]), (_H, 0.0, -_H, 0.0)),
    "-x": (np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]), (_H, 0.0, _H, 0.0)),
}


def _weighted_quantiles(values: np.ndarray, weights: np.ndarray, qs: list[float]) -> np.ndarray:
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(weights[order])
    cumulative /= cumulative[-1]
    picks = np.searchsorted(cumulative, qs, side="left").clip(0, len(values) - 1)
    return values[order][picks]


def robust_center_extent(g: Gaussians, trim: float = TRIM) -> tuple[np.ndarray, float]:
    """(opacity-weighted median of the means [3], longest side of the trimmed box)."""
    means = np.asarray(g.means, dtype=np.float64)
    finite = np.isfinite(means).all(axis=1)
    if not finite.any():
        raise InputError("the model has no Gaussian with finite coordinates")
    means = means[finite]
    weights = 1.0 / (1.0 + np.exp(-np.asarray(g.opacity_logits, dtype=np.float64)[finite]))
    weights = np.where(np.isfinite(weights), weights, 0.0)
    if not weights.sum() > 0:
        weights = np.ones(len(means))
    lo, mid, hi = np.stack(
        [_weighted_quantiles(means[:, a], weights, [trim, 0.5, 1 - trim]) for a in range(3)]
    ).T
    extent = float((hi - lo).max())
    if not extent > 0:  # a single point or a flat cluster: fall back to the full box
        extent = float((means.max(axis=0) - means.min(axis=0)).max()) or 1.0
    return mid, extent


def rotate_up(g: Gaussians, up: str) -> Gaussians:
    """The model rotated so that axis ``up`` points along +z (means and orientations).

    SH coefficients above degree 0 are not rotated: view-dependent colour is slightly off
    for ``up`` other than z, the shape and base colour are exact.
    """
    if up not in UP_AXES:
        raise InputError(f"up must be one of {', '.join(UP_AXES)}, got {up!r}")
    if up == "z":
        return g
    rotation, (w1, x1, y1, z1) = UP_AXES[up]
    means = (np.asarray(g.means, dtype=np.float64) @ rotation.T).astype(np.float32)
    w2, x2, y2, z2 = (g.quats[:, i].astype(np.float64) for i in range(4))
    quats = np.stack(  # rotation * q (Hamilton product)
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=1,
    ).astype(np.float32)
    return Gaussians(means, quats, g.log_scales.copy(), g.opacity_logits.copy(), g.sh.copy())


def to_scene_frame(
    g: Gaussians,
    size: float = 4.0,
    *,
    up: str = "z",
    center: tuple[float, float, float] | None = None,
) -> tuple[Gaussians, NormalizeTransform]:
    """Frames any model for the orbit: axis ``up`` turned onto +z, centred on its robust
    centre (or ``center``, in the model's own frame), the longest side of its robust box
    scaled to ``size``. Returns it and the transform from the (turned) model's frame, exact
    for ``up="z"``, where nothing is turned."""
    g = rotate_up(g, up)
    mid, extent = robust_center_extent(g)
    if center is not None:
        mid = UP_AXES[up][0] @ np.asarray(center, dtype=np.float64)
    transform = NormalizeTransform(
        center=(float(mid[0]), float(mid[1]), float(mid[2])), scale=float(size / extent)
    )
    return transform.gaussians_to_scene(g), transform
