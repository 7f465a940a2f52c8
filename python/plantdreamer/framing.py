"""Framing any 3DGS scene for the orbit: a robust centre and size, which axis is up, and
the orbit distance that keeps a whole model in every view.

Models from other tools carry stray Gaussians far from the subject (floaters, background
splats). A bounding box follows them, so the subject shrinks to a few pixels. Here the
centre is the opacity-weighted median of the means and the size is the longest side of the
opacity-weighted central 96% (2% trimmed on each side of every axis): a handful of far
Gaussians moves neither. Captured scenes are often y-down; ``up`` rotates the named axis
onto +z, the orbit's up.

``framed_distance`` is the evaluation orbit's default distance: the smallest at which every
Gaussian's 2-sigma sphere lies inside every view of the ring (``orbit_distance``), ``FRAME_MARGIN`` of the
half-image from its border. Strays do not count there either (``without_strays``): a Gaussian
farther from the robust centre than ``STRAY_EXTENTS`` robust sizes on some axis. A model's
own Gaussians lie within its full box, which for a plant (and any cluster whose tails are
not a few per cent of its opacity) is well inside twice its trimmed size, so a model without
strays is framed exactly as before; two floaters 500 sizes away no longer shrink it to a dot. A point p with camera-space x = a . p and depth z = d + f . p
is inside the side plane |x| = k z (k = tan(fov / 2) (1 - margin)) with a sphere of
radius r around it when d >= (|a . p| + r sqrt(1 + k^2)) / k - f . p: linear in p per side
of each view, so the distance is one matrix product and a maximum.
"""

from __future__ import annotations

import math

import numpy as np

from plantdreamer.cameras import Camera, orbit_ring
from plantdreamer.errors import InputError
from plantdreamer.gaussians import Gaussians
from plantdreamer.pointcloud import NormalizeTransform

__all__ = [
    "FRAME_MARGIN",
    "TRIM",
    "UP_AXES",
    "framed_distance",
    "orbit_distance",
    "robust_center_extent",
    "rotate_up",
    "to_scene_frame",
    "without_strays",
]

TRIM = 0.02  # weight trimmed on each side of every axis when measuring the size
FRAME_MARGIN = 0.05  # of the half-image, left free around a framed model in every view
FRAME_SIGMAS = 2.0  # a Gaussian's extent in the framing: this many of its largest sigma
STRAY_EXTENTS = 2.0  # farther from the robust centre than this many robust sizes: a stray
FAINT = 1.0 / 255.0  # Gaussians below this opacity draw nothing (the rasterizer skips them)
FRAME_AZIMUTHS = 72  # an orbit of fewer views is framed on this many too (5 degrees apart)
_CHUNK = 4096  # Gaussians per matrix product in orbit_distance (~25 MB at 192 views)

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


def without_strays(g: Gaussians) -> Gaussians:
    """``g`` less its strays: the Gaussians whose mean lies farther than ``STRAY_EXTENTS``
    robust sizes from the robust centre on some axis (``g`` itself when there are none)."""
    mid, extent = robust_center_extent(g)
    offset = np.abs(np.asarray(g.means, dtype=np.float64) - mid).max(axis=1)
    near = offset <= STRAY_EXTENTS * extent  # NaN means are no strays: orbit_distance drops them
    near |= ~np.isfinite(offset)
    return g if near.all() else g.subset(np.flatnonzero(near))


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


def orbit_distance(g: Gaussians, cameras: list[Camera]) -> float:
    """The smallest distance from the target (the origin) at which ``cameras`` (an orbit
    ring made at any distance, looking at the origin) see every Gaussian of ``g`` whole,
    with ``FRAME_MARGIN`` to spare; Gaussians fainter than ``FAINT`` do not count."""
    means = np.asarray(g.means, dtype=np.float64)
    radius = FRAME_SIGMAS * np.exp(np.asarray(g.log_scales, dtype=np.float64).max(axis=1))
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(g.opacity_logits, dtype=np.float64)))
    keep = np.isfinite(means).all(axis=1) & np.isfinite(radius) & (opacity >= FAINT)
    if not keep.any() or not cameras:
        raise InputError("no visible Gaussian to frame the evaluation orbit on")
    means, radius = means[keep], radius[keep]
    # Per view and side: p . (a / k - f) + r sqrt(1 + k^2) / k >= d, a = +-right or +-down.
    rows, offsets = [], []
    for cam in cameras:
        right, down, forward = cam.viewmat[:3, :3]
        kx = cam.width / (2.0 * cam.K[0, 0]) * (1.0 - FRAME_MARGIN)
        ky = cam.height / (2.0 * cam.K[1, 1]) * (1.0 - FRAME_MARGIN)
        for axis, k in ((right, kx), (down, ky)):
            for sign in (1.0, -1.0):
                rows.append(sign * axis / k - forward)
                offsets.append(math.sqrt(1.0 + k * k) / k)
    # One product of [p, r] with [a / k - f; sqrt(1 + k^2) / k] per chunk of Gaussians.
    coefficients = np.concatenate([np.stack(rows, axis=1), [offsets]], axis=0)
    points = np.concatenate([means, radius[:, None]], axis=1)
    far = -math.inf
    for start in range(0, len(points), _CHUNK):
        far = max(far, float((points[start : start + _CHUNK] @ coefficients).max()))
    if not far > 0:
        raise InputError("the model has no extent to frame the evaluation orbit on")
    return far


def framed_distance(
    g: Gaussians, views: int, elevation_deg: float, fovy_deg: float, width: int, height: int
) -> float:
    """The evaluation orbit's distance for ``g`` (in the scene frame, around the origin):
    ``orbit_distance`` of ``g`` less its strays over the ring's ``views``, and a ring of ``FRAME_AZIMUTHS`` where the
    orbit has fewer views, so the whole model stays in view at any azimuth (``render
    --eval-views`` of the same plant). Rounded up to 1e-6, a number that reads back the same
    (the matrix product's last bits may differ between CPUs)."""
    ring = orbit_ring(views, 1.0, elevation_deg, fovy_deg, width, height)
    if views < FRAME_AZIMUTHS:
        ring += orbit_ring(FRAME_AZIMUTHS, 1.0, elevation_deg, fovy_deg, width, height)
    return math.ceil(orbit_distance(without_strays(g), ring) * 1e6) / 1e6
