"""Mesh primitives built with numpy: tubes, surfaces of revolution and tipped grids.

Every primitive winds its triangles counter-clockwise seen from the outside, so face normals
(cross product of the first two edges) point out of tubes and solids of revolution, and out
of the ``up`` side of grids.
"""

from __future__ import annotations

import numpy as np

from plantdreamer.errors import InputError

MIN_RADIUS = 2e-4  # metres; thinner tubes would give slivers that samplers never hit


def rotate_batch(v: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotates rows ``v`` [m, 3] about unit rows ``axis`` [m, 3] by ``angle`` [m] radians."""
    c = np.cos(angle)[:, None]
    s = np.sin(angle)[:, None]
    dot = np.einsum("ij,ij->i", v, axis)[:, None]
    return v * c + np.cross(axis, v) * s + axis * dot * (1.0 - c)


def _ring_faces(rows: int, cols: int, offset: int = 0) -> np.ndarray:
    """Quads between consecutive rings of ``cols`` vertices (wrapping around), two triangles
    each, wound so the normal is d(column) x d(row)... see callers for the orientation."""
    r = np.arange(rows - 1)[:, None]
    j = np.arange(cols)[None, :]
    a = r * cols + j
    b = r * cols + (j + 1) % cols
    c = (r + 1) * cols + (j + 1) % cols
    d = (r + 1) * cols + j
    tris = np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], axis=2)
    return tris.reshape(-1, 3) + offset


def tube(
    points: np.ndarray, radii: np.ndarray, sides: int, cap_end: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """A tube of ``sides`` around a polyline [n, 3] with per-point radii [n].

    Frames are parallel-transported along the curve so the tube does not twist; the end is
    closed by a fan (the start is left open: stems start inside a parent stem or the soil).
    Returns (vertices [n*sides (+1), 3], faces [.., 3]).
    """
    points = np.asarray(points, dtype=np.float64)
    radii = np.asarray(radii, dtype=np.float64)
    points, radii = _drop_coincident(points, radii)
    n = len(points)
    if n < 2 or sides < 3:
        raise InputError("a tube needs at least 2 distinct points and 3 sides")
    seg = np.diff(points, axis=0)
    unit = seg / np.linalg.norm(seg, axis=1, keepdims=True)
    tangents = np.empty_like(points)
    tangents[0], tangents[-1] = unit[0], unit[-1]
    tangents[1:-1] = unit[:-1] + unit[1:]
    # A full reversal cancels the bisector: use the incoming direction there.
    flat = np.linalg.norm(tangents, axis=1) < 1e-9
    tangents[flat] = np.vstack([unit[:1], unit])[flat]
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    normals = np.empty_like(points)
    normal = _perpendicular(tangents[0])
    for i in range(n):
        normal = normal - tangents[i] * (normal @ tangents[i])
        length = np.linalg.norm(normal)
        normal = normal / length if length > 1e-9 else _perpendicular(tangents[i])
        normals[i] = normal
    binormals = np.cross(tangents, normals)
    phi = 2.0 * np.pi * (np.arange(sides) + 0.5) / sides
    r = np.maximum(radii, MIN_RADIUS)[:, None, None]
    ring = (
        np.cos(phi)[None, :, None] * normals[:, None]
        + np.sin(phi)[None, :, None] * binormals[:, None]
    )
    vertices = (points[:, None, :] + r * ring).reshape(-1, 3)
    faces = _ring_faces(n, sides)  # (a, b, c): d(phi) x d(along) -> outward
    if cap_end:
        tip = len(vertices)
        vertices = np.vstack([vertices, points[-1] + tangents[-1] * float(r[-1, 0, 0]) * 0.3])
        j = np.arange(sides)
        last = (n - 1) * sides
        cap = np.stack([np.full(sides, tip), last + j, last + (j + 1) % sides], axis=1)
        faces = np.vstack([faces, cap])
    return vertices, faces


def _drop_coincident(
    points: np.ndarray, radii: np.ndarray, eps: float = 1e-6
) -> tuple[np.ndarray, np.ndarray]:
    """Drops points within ``eps`` of the previous kept one (they would make slivers); the
    tip replaces the last kept point if it was dropped, so the tube still ends there."""
    keep = [0]
    for i in range(1, len(points)):
        if np.linalg.norm(points[i] - points[keep[-1]]) > eps:
            keep.append(i)
    if len(points) and keep[-1] != len(points) - 1 and len(keep) > 1:
        keep[-1] = len(points) - 1
    return points[keep], radii[keep]


def _perpendicular(t: np.ndarray) -> np.ndarray:
    axis = np.array([1.0, 0.0, 0.0]) if abs(t[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    p = axis - t * (axis @ t)
    return p / np.linalg.norm(p)


def revolve(profile: np.ndarray, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Surface of revolution about the z axis of a (r, z) profile [k, 2].

    Profile points with r == 0 (only allowed first or last) become a single apex vertex.
    Normals are d(phi) x d(profile): walking the profile with the solid on the left-hand side
    seen from +phi... concretely: upward along an outer wall -> outward; inward along a top
    surface -> up; outward along a bottom -> down.
    """
    profile = np.asarray(profile, dtype=np.float64)
    phi = 2.0 * np.pi * np.arange(segments) / segments
    axis_start = profile[0, 0] == 0.0
    axis_end = profile[-1, 0] == 0.0
    body = profile[int(axis_start) : len(profile) - int(axis_end)]
    rows = len(body)
    ring = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    vertices = np.concatenate(
        [
            body[:, None, 0:1] * ring[None, :, :],
            np.broadcast_to(body[:, None, 1:2], (rows, segments, 1)),
        ],
        axis=2,
    ).reshape(-1, 3)
    # _ring_faces rows run along the profile, columns along phi: (a,b,c) = d(phi) x d(profile).
    faces = [_ring_faces(rows, segments)]
    j = np.arange(segments)
    jn = (j + 1) % segments
    extra: list[list[float]] = []
    if axis_start:
        apex = rows * segments + len(extra)
        extra.append([0.0, 0.0, profile[0, 1]])
        faces.append(np.stack([np.full(segments, apex), jn, j], axis=1))
    if axis_end:
        apex = rows * segments + len(extra)
        extra.append([0.0, 0.0, profile[-1, 1]])
        last = (rows - 1) * segments
        faces.append(np.stack([np.full(segments, apex), last + j, last + jn], axis=1))
    if extra:
        vertices = np.vstack([vertices, np.array(extra)])
    return vertices, np.vstack(faces)


def tipped_grid_faces(rows: int, cols: int) -> np.ndarray:
    """Faces of a grid whose first and last rows are single tip vertices.

    Vertex order: tip 0, then ``rows - 2`` interior rows of ``cols`` vertices, then tip 1.
    With rows running along +u (heading) and columns along +v (left), the normals point
    along u x v (the grid's up side).
    """
    inner = rows - 2
    if inner < 1 or cols < 2:
        raise InputError("a tipped grid needs at least 3 rows and 2 columns")
    j = np.arange(cols - 1)
    start = np.stack([np.zeros(cols - 1, dtype=np.int64), 1 + j, 2 + j], axis=1)
    r = np.arange(inner - 1)[:, None]
    a = 1 + r * cols + j
    b = 1 + (r + 1) * cols + j
    c = b + 1
    d = a + 1
    quads = np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], axis=2).reshape(-1, 3)
    tip = 1 + inner * cols
    last = 1 + (inner - 1) * cols
    end = np.stack([last + j, np.full(cols - 1, tip), last + j + 1], axis=1)
    return np.vstack([start, quads, end]).astype(np.int64)
