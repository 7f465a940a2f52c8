"""Uniform, area-weighted sampling of a ``PlantMesh`` surface into a labelled point cloud."""

from __future__ import annotations

import numbers

import numpy as np

from plantdreamer.cloud import PointCloud, check_point_count
from plantdreamer.errors import InputError
from plantdreamer.lsystem.mesh import PlantMesh


def sample_points(
    mesh: PlantMesh, n: int = 100_000, seed: int = 0, boundary_distance: bool = False
) -> PointCloud:
    """``n`` points uniformly distributed over the surface area of ``mesh``.

    A face is picked with probability proportional to its area, then a point uniformly
    inside it (``sqrt`` barycentric warp). Colours are interpolated from the vertices;
    normals are the face normals (from the winding); attributes ``label`` (OrganClass) and
    ``instance`` (leaf id or -1) come from the face's vertices. With ``boundary_distance``,
    attribute ``boundary_distance`` (float32) is each point's distance to its part's
    boundary (``PlantMesh.boundary_distance``), interpolated from the face's corners.
    """
    check_point_count(n)
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    areas, normals = mesh.face_areas_normals()
    total = float(areas.sum())
    if not (len(areas) and np.isfinite(total) and total > 0):
        raise InputError("the mesh has no surface area to sample")
    rng = np.random.default_rng(int(seed))
    cumulative = np.cumsum(areas)
    picks = rng.random(int(n)) * cumulative[-1]
    face = np.minimum(np.searchsorted(cumulative, picks, side="right"), len(areas) - 1)
    # Zero-area faces can never be picked: searchsorted skips flat stretches of the cumsum.

    r1 = np.sqrt(rng.random(int(n)))
    r2 = rng.random(int(n))
    weights = np.stack([1.0 - r1, r1 * (1.0 - r2), r1 * r2], axis=1)  # [n, 3]
    corners = mesh.faces[face]  # [n, 3]
    positions = np.einsum("nk,nkd->nd", weights, mesh.vertices[corners].astype(np.float64))
    colors = np.einsum("nk,nkd->nd", weights, mesh.colors[corners].astype(np.float64))
    first = corners[:, 0]
    attributes = {
        "label": mesh.labels[first].astype(np.int32),
        "instance": mesh.instances[first].astype(np.int32),
    }
    if boundary_distance:
        corner_distance = mesh.boundary_distance()[corners]  # [n, 3]; inf: closed part
        closed = np.isinf(corner_distance).any(axis=1)
        inside = np.einsum("nk,nk->n", weights, np.where(closed[:, None], 0.0, corner_distance))
        attributes["boundary_distance"] = np.where(closed, np.inf, inside).astype(np.float32)
    return PointCloud(
        positions=positions.astype(np.float32),
        colors=np.clip(colors, 0.0, 1.0).astype(np.float32),
        normals=normals[face].astype(np.float32),
        attributes=attributes,
    )
