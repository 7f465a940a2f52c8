"""Plain geometry of the traits: polyline lengths, a plane's inclination, the convex hull of
points seen from above, its area and diameter (numpy; no SciPy in the package)."""

from __future__ import annotations

import math

import numpy as np

FILTER_DIRECTIONS = 32  # extreme points whose polygon's inside holds no hull vertex


def polyline_length(points: np.ndarray) -> float:
    """The length of the polyline through ``points`` [n, 3] (0 for fewer than 2)."""
    p = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


def inclination_deg(normal: np.ndarray) -> float:
    """The angle between a (unit) surface normal and the zenith, in degrees: 0 for a
    horizontal blade facing up, 90 for a vertical one, above 90 facing down."""
    n = np.asarray(normal, dtype=np.float64)
    length = float(np.linalg.norm(n))
    if length == 0.0:
        return float("nan")
    return math.degrees(math.acos(max(-1.0, min(1.0, float(n[2]) / length))))


def azimuth_deg(direction: np.ndarray) -> float:
    """The compass direction of ``direction`` seen from above, in degrees from +x towards
    +y, in [0, 360); NaN for a vertical direction."""
    x, y = float(direction[0]), float(direction[1])
    if x == 0.0 and y == 0.0:
        return float("nan")
    return math.degrees(math.atan2(y, x)) % 360.0


def convex_hull_2d(points: np.ndarray) -> np.ndarray:
    """The convex hull of 2-D ``points`` [n, 2] (float64), counter-clockwise, without
    collinear points (Andrew's monotone chain); fewer than 3 distinct points come back as
    they are. Points strictly inside the polygon of the extreme points in 32 directions
    are left out first (Akl-Toussaint): no hull vertex is among them."""
    p = np.asarray(points, dtype=np.float64)
    p = p[_outside_polygon(p)] if len(p) > 4 * FILTER_DIRECTIONS else p
    p = np.unique(p, axis=0)  # sorted by x, then y
    if len(p) < 3:
        return p

    def half(rows: np.ndarray) -> list[np.ndarray]:
        chain: list[np.ndarray] = []
        for q in rows:
            while len(chain) >= 2 and _cross(chain[-2], chain[-1], q) <= 0:
                chain.pop()
            chain.append(q)
        return chain

    lower = half(p)
    upper = half(p[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _outside_polygon(p: np.ndarray) -> np.ndarray:
    """bool [n]: not strictly inside the convex polygon through the points extreme in
    ``FILTER_DIRECTIONS`` directions (in angular order). Element-wise only: a matrix
    product would wait on BLAS's threads."""
    x, y = np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1])
    angles = 2 * np.pi * np.arange(FILTER_DIRECTIONS) / FILTER_DIRECTIONS
    extreme = [int(np.argmax(x * math.cos(a) + y * math.sin(a))) for a in angles]
    corners = p[extreme]
    corners = corners[np.r_[True, (np.diff(corners, axis=0) != 0).any(axis=1)]]
    if len(corners) > 1 and (corners[0] == corners[-1]).all():
        corners = corners[:-1]
    if len(corners) < 3:
        return np.ones(len(p), dtype=bool)
    inside = np.ones(len(p), dtype=bool)
    for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True):
        inside &= (b[0] - a[0]) * (y - a[1]) > (b[1] - a[1]) * (x - a[0])
    return ~inside


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def polygon_area(polygon: np.ndarray) -> float:
    """The area of a simple polygon [k, 2] (shoelace; 0 for fewer than 3 vertices)."""
    if len(polygon) < 3:
        return 0.0
    x, y = polygon[:, 0], polygon[:, 1]
    return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2.0)


def diameter(polygon: np.ndarray) -> float:
    """The largest distance between two vertices of ``polygon`` [k, 2] (a hull's is the
    largest distance between any two of the points it encloses)."""
    if len(polygon) < 2:
        return 0.0
    d = polygon[:, None, :] - polygon[None, :, :]
    return float(np.sqrt((d * d).sum(axis=2).max()))


def canopy(points: np.ndarray) -> tuple[float, float]:
    """The canopy of 3-D ``points`` seen from above: its width (the largest horizontal
    distance between two of them) and the area of their convex hull on the ground."""
    if len(points) == 0:
        return 0.0, 0.0
    hull = convex_hull_2d(np.asarray(points)[:, :2])
    return diameter(hull), polygon_area(hull)


def extent(points: np.ndarray) -> list[float]:
    """The size of the axis-aligned box around ``points`` [n, 3] (zeros when empty)."""
    if len(points) == 0:
        return [0.0, 0.0, 0.0]
    p = np.asarray(points, dtype=np.float64)
    return (p.max(axis=0) - p.min(axis=0)).tolist()
