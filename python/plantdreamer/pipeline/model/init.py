"""Initial Gaussians from a point cloud (released code's rules) and colour-init ablations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.gaussians import Gaussians, rgb_to_sh_dc, sh_coeff_count
from plantdreamer.settings import setting

COLOR_INITS = ("original", "noise", "black", "white")
INIT_SHAPES = ("surface", "sphere")

# Leaf green for clouds without colours (an L-System mesh always has colours).
DEFAULT_RGB = (0.25, 0.45, 0.15)
# A surface-aligned Gaussian's scale along the surface normal, as a fraction of its scale in
# the surface: thin enough that a leaf seen edge-on stays a line (docs/labels.md).
SURFACE_THICKNESS = 0.05
# A Gaussian's scale is at most this fraction of its distance to the surface's edge: its
# 2-sigma ellipse stays on the surface (docs/labels.md).
EDGE_MARGIN = 0.5


@dataclass
class InitConfig:
    """The initialisation section: how the source points become the first Gaussians."""

    sh_degree: int = setting(0, "SH degree optimised.", range=(0, 3))
    color_init: str = setting("original", "Colours of the initial Gaussians.", choices=COLOR_INITS)
    opacity_init: float | None = setting(
        None,
        "Initial opacity, in (0, 1) (its logit must be finite).",
        default_text="0.7 for L-System meshes, 0.1 for point clouds",
        range=(0.0, 1.0),
        open=(True, True),
    )
    init_scale: str = setting(
        "mean", "Initial scale from the 3 nearest neighbours' distances.", choices=("mean", "rms")
    )
    init_shape: str = setting(
        "surface",
        "Initial Gaussians on an L-System mesh: flat discs in the surface, or spheres "
        "(released); point clouds always get spheres.",
        choices=INIT_SHAPES,
    )

    def opacity(self, captured: bool) -> float:
        """The initial opacity: ``opacity_init``, else the released code's default for a
        point cloud (``captured``) or an L-System mesh."""
        if self.opacity_init is not None:
            return self.opacity_init
        return 0.1 if captured else 0.7


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
    normals: np.ndarray | None = None,
    boundary_distance: np.ndarray | None = None,
) -> Gaussians:
    """Gaussians at the points, of scale s = ``neighbour_spacing`` (mean distance to the 3
    nearest neighbours by default): isotropic spheres, or with ``normals`` ([N, 3], the
    surface's normal at each point) flat discs in the surface, of scale s in it and
    ``SURFACE_THICKNESS`` s along the normal. ``boundary_distance`` ([N], each point's
    distance to the edge of its surface) caps s at ``EDGE_MARGIN`` times it, so that a disc
    near a leaf's outline does not reach past it.

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
    if boundary_distance is not None:
        if boundary_distance.shape != (n,):
            raise InputError(f"need one boundary distance per point, got {boundary_distance.shape}")
        dist = np.minimum(dist, EDGE_MARGIN * boundary_distance.astype(np.float32))
    scale = np.maximum(dist, floor).astype(np.float32)
    sh = np.zeros((n, sh_coeff_count(sh_degree), 3), dtype=np.float32)
    sh[:, 0] = rgb_to_sh_dc(colors)
    log_scales = np.repeat(np.log(scale)[:, None], 3, axis=1)
    quats = np.zeros((n, 4), dtype=np.float32)
    quats[:, 0] = 1.0
    if normals is not None:
        if normals.shape != (n, 3):
            raise InputError(f"need one normal per point, got shape {list(normals.shape)}")
        quats, flat = normal_rotations(normals)
        log_scales[flat, 2] += np.log(SURFACE_THICKNESS)
    logit = np.log(opacity / (1.0 - opacity))
    return Gaussians(
        means=np.ascontiguousarray(points, dtype=np.float32),
        quats=quats,
        log_scales=log_scales.astype(np.float32),
        opacity_logits=np.full(n, logit, dtype=np.float32),
        sh=sh,
        labels=None if labels is None else np.ascontiguousarray(labels, dtype=np.int32),
    )


def normal_rotations(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit quaternions (w, x, y, z) turning the local z axis onto each normal, and where the
    normal was usable (finite, non-zero; elsewhere the identity)."""
    nrm = np.asarray(normals, dtype=np.float64)
    length = np.linalg.norm(nrm, axis=1)
    usable = np.isfinite(length) & (length > 0)
    unit = np.where(usable[:, None], nrm / np.where(usable, length, 1.0)[:, None], [0, 0, 1.0])
    # Half-way rotation from z to n: q = (1 + z.n, z x n), normalised; for n = -z, a half
    # turn about x.
    q = np.stack([1.0 + unit[:, 2], -unit[:, 1], unit[:, 0], np.zeros(len(unit))], axis=1)
    opposite = q[:, 0] < 1e-12
    q[opposite] = (0.0, 1.0, 0.0, 0.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q.astype(np.float32), usable
