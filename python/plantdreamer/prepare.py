"""Preparing an input point cloud for Gaussian initialisation.

Steps, each reported with its point count: drop non-finite points, statistical outlier
removal (k = 20, std ratio 3.0), voxel grid down to a target count (+-5%), and optionally
centring on the bounding-box midpoint with the longest side scaled to 4 units.

Order: outliers are removed first, on the raw density, as the paper describes; the
released code downsamples first (``sor_after_voxel=True``). Removing them first keeps stray
points from inflating the bounding box that the voxel search and normalisation use, and the
final count then lands within the target band. Voxel averaging cannot keep normals; integer
attributes named in ``label_fields`` (class and instance ids) are kept, each voxel taking the
majority value of its points (``plantdreamer.labels.voxel_majority``); other attributes are
dropped.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from plantdreamer.cloud import PointCloud
from plantdreamer.errors import InputError
from plantdreamer.labels import voxel_keys, voxel_majority
from plantdreamer.pointcloud import (
    NormalizeTransform,
    downsample_to_count,
    normalize,
    remove_statistical_outliers,
)

# The steps' defaults; generate's input section (pipeline/model/source.py) and the `prepare`
# command take theirs from here.
TARGET_POINTS = 100_000
SOR_NEIGHBORS = 20
SOR_STD = 3.0
TOLERANCE = 0.05  # the voxel grid aims at target +- this fraction


@dataclass
class PrepareReport:
    """Point counts after each step, in order, e.g. [("input", 1000000), ...]."""

    counts: list[tuple[str, int]] = field(default_factory=list)
    voxel_size: float = 0.0


def prepare_cloud(
    cloud: PointCloud,
    target: int | None = TARGET_POINTS,
    sor_neighbors: int = SOR_NEIGHBORS,
    sor_std: float = SOR_STD,
    normalize_size: float | None = None,
    tolerance: float = TOLERANCE,
    log: Callable[[str, int], None] | None = None,
    sor_after_voxel: bool = False,
    label_fields: Sequence[str] = (),
) -> tuple[PointCloud, NormalizeTransform | None, PrepareReport]:
    """Runs the preparation steps; ``target=None`` skips downsampling, ``sor_neighbors=0``
    skips outlier removal, ``normalize_size=None`` skips normalisation,
    ``sor_after_voxel`` swaps the two middle steps (the released code's order). The attributes
    named in ``label_fields`` survive every step (majority vote per voxel)."""
    report = PrepareReport()

    def step(name: str, c: PointCloud) -> PointCloud:
        report.counts.append((name, len(c)))
        if log is not None:
            log(name, len(c))
        return c

    cloud = step("input", cloud)
    finite = np.isfinite(cloud.positions).all(axis=1)
    if not finite.all():
        cloud = step("finite", cloud.subset(np.flatnonzero(finite)))
    if len(cloud) == 0:
        raise InputError("the cloud has no points with finite coordinates")
    if cloud.colors is not None:
        bad = ~np.isfinite(cloud.colors).all(axis=1)
        if bad.any():
            warnings.warn(
                f"{int(bad.sum())} of {len(cloud)} points have NaN or Inf colours; "
                "those points were dropped",
                stacklevel=2,
            )
            cloud = step("finite colours", cloud.subset(np.flatnonzero(~bad)))
            if len(cloud) == 0:
                raise InputError("no point of the cloud has a finite colour")

    def remove_outliers(c: PointCloud) -> PointCloud:
        if sor_neighbors <= 0:
            return c
        if len(c) < sor_neighbors:
            raise InputError(
                f"the cloud has {len(c)} points, fewer than --sor-neighbors={sor_neighbors}"
            )
        c = step(
            "outliers removed",
            c.subset(remove_statistical_outliers(c.positions, sor_neighbors, sor_std)),
        )
        if len(c) == 0:
            raise InputError("outlier removal kept no points (are all points duplicates?)")
        return c

    def downsample(c: PointCloud) -> PointCloud:
        if target is None:
            return c
        points, colors, report.voxel_size = downsample_to_count(
            c.positions,
            min(target, len(c)),
            c.colors,
            tolerance=tolerance,  # more keeps all
        )
        labels = {name: c.attributes[name] for name in label_fields}
        if report.voxel_size > 0.0 and labels:
            voxel = voxel_keys(c.positions, report.voxel_size)
            labels = {name: voxel_majority(voxel, v) for name, v in labels.items()}
        return step("downsampled", PointCloud(points, colors, attributes=labels))

    if sor_after_voxel:
        cloud = remove_outliers(downsample(cloud))
    else:
        cloud = downsample(remove_outliers(cloud))
    transform = None
    if normalize_size is not None:
        points, transform = normalize(cloud.positions, normalize_size)
        labels = {name: cloud.attributes[name] for name in label_fields}
        cloud = PointCloud(points, cloud.colors, attributes=labels)
    return cloud, transform, report
