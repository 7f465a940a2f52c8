"""Point-cloud filters (native, parallel, deterministic) and normalisation.

Points are [N, 3] float32 or float64 arrays (other dtypes are converted to float32);
outputs keep the input precision. Distances are computed in float64 as Open3D does, so
:func:`remove_statistical_outliers` keeps exactly the points Open3D 0.20's
``remove_statistical_outlier`` keeps and :func:`voxel_downsample` returns the same voxel
means as its ``voxel_down_sample``. Non-finite coordinates, empty clouds and too few points
raise :class:`~plantdreamer.errors.InputError`, and so do integer arguments (``k``,
``nb_neighbors``, ``target``, ``threads``) that are negative, too large or not integers
(a float is never truncated). ``threads`` runs a call on its own pool of that many threads
(default: all cores; at most 4 x the cores); results do not depend on it.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from plantdreamer import _core
from plantdreamer.errors import InputError

if TYPE_CHECKING:
    from plantdreamer.gaussians import Gaussians

__all__ = [
    "NormalizeTransform",
    "downsample_to_count",
    "knn",
    "knn_mean_distance",
    "normalize",
    "remove_statistical_outliers",
    "voxel_downsample",
]


def _points(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points)
    if p.dtype not in (np.float32, np.float64):
        p = p.astype(np.float32)
    return np.ascontiguousarray(p)


def _colors(colors: np.ndarray | None) -> np.ndarray | None:
    return None if colors is None else np.ascontiguousarray(colors, dtype=np.float32)


def remove_statistical_outliers(
    points: np.ndarray,
    nb_neighbors: int = 20,
    std_ratio: float = 2.0,
    *,
    threads: int | None = None,
) -> np.ndarray:
    """Indices (int64, ascending) of the points kept by statistical outlier removal.

    Open3D 0.20 legacy semantics: a point's score is its mean distance to its
    ``nb_neighbors`` nearest points, itself included; with mean m (sum of positive scores
    / N) and Bessel standard deviation s (over positive scores), a point is kept iff
    0 < score < m + std_ratio * s. Points with ``nb_neighbors - 1`` exact duplicates score 0
    and are removed, as in Open3D. Needs N >= nb_neighbors.
    """
    return _core.remove_statistical_outliers(
        _points(points), nb_neighbors, float(std_ratio), threads
    )


def voxel_downsample(
    points: np.ndarray,
    voxel_size: float,
    colors: np.ndarray | None = None,
    *,
    threads: int | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Mean position (and mean colour) of the points in each occupied voxel.

    Open3D legacy semantics: grid origin = min bound - voxel_size / 2, voxel index =
    floor((p - origin) / voxel_size). Output rows are sorted by voxel index (x, then y,
    then z). A voxel_size that would overflow a 32-bit voxel index is an InputError.
    """
    return _core.voxel_downsample(_points(points), float(voxel_size), _colors(colors), threads)


def downsample_to_count(
    points: np.ndarray,
    target: int,
    colors: np.ndarray | None = None,
    tolerance: float = 0.05,
    *,
    threads: int | None = None,
) -> tuple[np.ndarray, np.ndarray | None, float]:
    """Voxel-downsamples to ``target`` points within +-``tolerance`` (relative).

    Returns (points, colors, voxel_size). The voxel size is found by bisection (on its
    log). A cloud with at most target * (1 + tolerance) points is returned as is, with
    voxel_size 0.0. When no voxel size lands in the band (a cloud of a few heavy
    clusters), an InputError names the closest count.
    """
    return _core.downsample_to_count(
        _points(points), target, _colors(colors), float(tolerance), threads
    )


def knn(points: np.ndarray, k: int, *, threads: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest other points of every point: (indices int64 [N, k], distances float32
    [N, k]), nearest first. Among equidistant candidates the smaller index wins, so the
    result is deterministic and independent of the thread count. Needs N > k.
    """
    return _core.knn(_points(points), k, threads)


def knn_mean_distance(points: np.ndarray, k: int = 3, *, threads: int | None = None) -> np.ndarray:
    """Mean distance (float32 [N]) from each point to its k nearest other points.

    PlantDreamer initialises each Gaussian with this isotropic scale (k = 3). Needs N > k.
    """
    return _core.knn_mean_distance(_points(points), k, threads)


@dataclass(frozen=True)
class NormalizeTransform:
    """``apply``: (p - center) * scale; ``invert`` restores the original frame.

    center: bounding-box midpoint of the original cloud; scale: size / longest side.
    """

    center: tuple[float, float, float]
    scale: float

    def apply(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points)
        return ((p - np.asarray(self.center)) * self.scale).astype(p.dtype, copy=False)

    def invert(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points)
        return (p / self.scale + np.asarray(self.center)).astype(p.dtype, copy=False)

    def gaussians_to_scene(self, g: Gaussians, means: np.ndarray | None = None) -> Gaussians:
        """Gaussians of the original frame in the normalised one (``apply`` to the means,
        in float64: ``means`` when the caller holds them more precisely than ``g``)."""
        original = np.asarray(g.means if means is None else means, dtype=np.float64)
        return g.moved(self.apply(original), math.log(self.scale))

    def gaussians_to_original(self, g: Gaussians, offset: np.ndarray | None = None) -> Gaussians:
        """Normalised Gaussians back in the original frame (``invert``, in float64), minus
        ``offset`` before the float32 cast (no precision lost to a far origin)."""
        means = self.invert(g.means.astype(np.float64))
        if offset is not None:
            means = means - offset
        return g.moved(means, -math.log(self.scale))

    def to_dict(self) -> dict[str, object]:
        return {"center": list(self.center), "scale": self.scale}

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> NormalizeTransform:
        try:
            center = tuple(float(c) for c in d["center"])  # type: ignore[attr-defined]
            scale = float(d["scale"])  # type: ignore[arg-type]
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"not a normalisation transform: {d!r}") from exc
        if len(center) != 3 or not (math.isfinite(scale) and scale > 0):
            raise InputError(f"not a normalisation transform: {d!r}")
        return cls(center=center, scale=scale)  # type: ignore[arg-type]

    def save(self, path: str | os.PathLike[str]) -> None:
        from plantdreamer.atomic import write_json

        write_json(path, self.to_dict())

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> NormalizeTransform:
        with open(path) as f:
            return cls.from_dict(json.load(f))


def normalize(points: np.ndarray, size: float = 4.0) -> tuple[np.ndarray, NormalizeTransform]:
    """Centres the cloud on its bounding-box midpoint and scales its longest side to ``size``.

    Returns the moved points (same dtype) and the transform that restores the original frame.
    """
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
        raise InputError(f"points must be a non-empty [N, 3] array, got shape {list(p.shape)}")
    if not np.isfinite(p).all():
        raise InputError("points contain NaN or Inf; drop them before normalising")
    if not (math.isfinite(size) and size > 0):
        raise InputError(f"size must be positive, got {size}")
    lo = p.min(axis=0).astype(np.float64)
    hi = p.max(axis=0).astype(np.float64)
    # Half-extents: hi - lo overflows float64 for clouds spanning more than 1.8e308.
    half = float((hi / 2.0 - lo / 2.0).max())
    if half == 0.0:
        raise InputError("all points are identical: the cloud has no extent to normalise")
    center = lo / 2.0 + hi / 2.0
    scale = (size / 2.0) / half
    if not (math.isfinite(scale) and scale > 0.0):
        raise InputError(f"the cloud's extent ({2.0 * half:.3g}) cannot be scaled to {size}")
    t = NormalizeTransform(center=tuple(float(c) for c in center), scale=scale)  # type: ignore[arg-type]
    moved = t.apply(p)
    if not np.isfinite(moved).all():
        raise InputError("the cloud's coordinates overflow when centred; rescale it first")
    return moved, t
