"""A splat PLY as the viewer draws it: centres, covariances, colours, opacities, labels."""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.gaussians import Gaussians, sh_dc_to_rgb
from plantdreamer.io import read_ply_columns, read_splat_ply

# Organ label -> colour (0-1). The classes are plantdreamer.lsystem.OrganClass, with 0 for
# background; -1 (no label) and unknown classes are drawn in UNLABELLED_COLOR.
LABEL_COLORS: dict[int, tuple[float, float, float]] = {
    0: (0.55, 0.55, 0.55),  # background
    1: (0.20, 0.75, 0.25),  # leaf
    2: (0.60, 0.35, 0.10),  # stem
    3: (0.85, 0.45, 0.30),  # pot
    4: (0.35, 0.22, 0.12),  # soil
}
LABEL_NAMES = {0: "background", 1: "leaf", 2: "stem", 3: "pot", 4: "soil"}
UNLABELLED_COLOR = (0.85, 0.20, 0.85)


@dataclass
class SplatScene:
    """What the browser draws for one PLY; arrays are float32, N Gaussians."""

    name: str
    centers: np.ndarray  # [N, 3]
    covariances: np.ndarray  # [N, 3, 3]
    rgbs: np.ndarray  # [N, 3] in [0, 1], from the SH DC term (view-independent)
    opacities: np.ndarray  # [N, 1] in [0, 1]
    labels: np.ndarray | None  # [N] int32 organ classes, or None when the file has none

    def __len__(self) -> int:
        return int(self.centers.shape[0])

    def label_rgbs(self) -> np.ndarray:
        """[N, 3] colours of the organ labels; needs labels."""
        if self.labels is None:
            raise ValueError("this scene has no labels")
        palette = np.array([UNLABELLED_COLOR, *LABEL_COLORS.values()], dtype=np.float32)
        codes = np.array(list(LABEL_COLORS), dtype=np.int64)
        index = np.searchsorted(codes, self.labels)
        known = (index < len(codes)) & (codes[np.minimum(index, len(codes) - 1)] == self.labels)
        return palette[np.where(known, index + 1, 0)]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Min and max corners of the centres (zeros for an empty scene)."""
        if len(self) == 0:
            return np.zeros(3, np.float32), np.zeros(3, np.float32)
        return self.centers.min(axis=0), self.centers.max(axis=0)


def covariances(g: Gaussians) -> np.ndarray:
    """[N, 3, 3] world covariances R diag(s^2) R^T of the Gaussians (quaternions normalised)."""
    q = g.quats.astype(np.float64)
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
    w, x, y, z = q.T
    rot = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )
    scaled = rot * np.exp(g.log_scales.astype(np.float64))[:, None, :]
    return (scaled @ scaled.transpose(0, 2, 1)).astype(np.float32)


def scene_from_gaussians(g: Gaussians, name: str, labels: np.ndarray | None) -> SplatScene:
    opacity = 1.0 / (1.0 + np.exp(-g.opacity_logits.astype(np.float64)))
    return SplatScene(
        name=name,
        centers=np.ascontiguousarray(g.means, dtype=np.float32),
        covariances=covariances(g),
        rgbs=np.clip(sh_dc_to_rgb(g.sh[:, 0, :]), 0.0, 1.0),
        opacities=opacity.astype(np.float32)[:, None],
        labels=labels,
    )


def load_scene(path: str | os.PathLike[str]) -> SplatScene:
    """Reads a splat PLY (INRIA layout) and its ``label`` property when it has one (integer,
    or float with whole values, as `render --labels` and `generate` accept).

    Gaussians with a non-finite position, rotation, scale, opacity or colour are dropped
    with a warning saying how many (they would put the camera at NaN). Raises PlyError for
    a file that is not a 3DGS PLY (for example a plain point cloud), InputError when no
    Gaussian is finite.
    """
    g = read_splat_ply(path)
    has_label = "label" in read_ply_columns(path)
    finite = finite_gaussians(g)
    if not finite.all():
        warnings.warn(
            f"{int((~finite).sum())} of {len(g)} Gaussians have NaN or Inf parameters "
            "(position, rotation, scale, opacity or colour); they are not shown",
            stacklevel=2,
        )
        if not finite.any():
            raise InputError(f"{Path(path).name}: no Gaussian has finite parameters")
        g = g.subset(np.flatnonzero(finite))
    labels = g.labels[:, 0].copy() if has_label and g.labels is not None else None
    return scene_from_gaussians(g, Path(path).name, labels)


def side_by_side(scenes: list[SplatScene]) -> SplatScene:
    """The scenes in one row along x, in order, each moved so that its bounding box begins
    a tenth of the widest one after the previous box ends; one scene is itself."""
    if len(scenes) == 1:
        return scenes[0]
    boxes = [s.bounds() for s in scenes]
    gap = 0.1 * max(max(float(hi[0] - lo[0]) for lo, hi in boxes), 1e-3)
    centers, x = [], 0.0
    for scene, (lo, hi) in zip(scenes, boxes, strict=True):
        moved = scene.centers.copy()
        moved[:, 0] += np.float32(x - float(lo[0]))
        centers.append(moved)
        x += float(hi[0] - lo[0]) + gap
    labelled = all(s.labels is not None for s in scenes)
    return SplatScene(
        name=f"{len(scenes)} plants ({', '.join(s.name for s in scenes)})",
        centers=np.concatenate(centers),
        covariances=np.concatenate([s.covariances for s in scenes]),
        rgbs=np.concatenate([s.rgbs for s in scenes]),
        opacities=np.concatenate([s.opacities for s in scenes]),
        labels=np.concatenate([s.labels for s in scenes]) if labelled else None,  # type: ignore[misc]
    )


def finite_gaussians(g: Gaussians) -> np.ndarray:
    """[N] bool: every parameter the viewer draws is finite."""
    ok = np.isfinite(g.opacity_logits)
    for values in (g.means, g.quats, g.log_scales, g.sh[:, 0, :]):
        ok &= np.isfinite(values).all(axis=1)
    return ok
