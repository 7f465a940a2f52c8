"""Mesh primitives: tubes, surfaces of revolution and tipped grids wind outwards."""

import numpy as np
import pytest

from plantdreamer.errors import InputError
from plantdreamer.lsystem.geometry import revolve, tipped_grid_faces, tube
from plantdreamer.lsystem.organs import PotShape, build_pot, build_soil


def face_normals(vertices, faces):
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True), area, tri.mean(axis=1)


def assert_oriented_manifold_edges(faces):
    """Every directed edge appears at most once (two faces sharing an edge traverse it in
    opposite directions: consistent winding)."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    unique = np.unique(edges, axis=0)
    assert len(unique) == len(edges), "some directed edge is used twice: winding flips"


@pytest.mark.parametrize("sides", [3, 4, 8])
def test_tube_normals_point_away_from_the_axis(sides):
    t = np.linspace(0, 1, 12)
    points = np.stack([0.3 * np.sin(2 * t), 0.2 * t, t], axis=1)
    vertices, faces = tube(points, np.linspace(0.02, 0.01, 12), sides)
    normals, area, centres = face_normals(vertices, faces)
    assert area.min() > 1e-8
    side = faces.max(axis=1) < len(points) * sides  # not the tip cap
    nearest = points[np.argmin(np.linalg.norm(centres[side, None] - points[None], axis=2), 1)]
    outward = np.einsum("ij,ij->i", normals[side], centres[side] - nearest)
    assert (outward > 0).all()
    cap = ~side
    assert (normals[cap] @ (points[-1] - points[-2]) > 0).all()
    assert_oriented_manifold_edges(faces)


def test_tube_rejects_a_single_point():
    with pytest.raises(InputError):
        tube(np.zeros((1, 3)), np.ones(1), 6)


def test_revolved_cylinder_with_caps_is_closed_and_outward():
    profile = np.array([[0, 0], [1, 0], [1, 2], [0, 2]], dtype=float)
    vertices, faces = revolve(profile, 16)
    normals, area, centres = face_normals(vertices, faces)
    assert area.min() > 1e-6
    radial = centres.copy()
    radial[:, 2] = 0
    side = np.abs(normals[:, 2]) < 1e-9
    assert (np.einsum("ij,ij->i", normals[side], radial[side]) > 0).all()
    assert (normals[centres[:, 2] < 1e-9, 2] < -0.99).all()
    assert (normals[centres[:, 2] > 2 - 1e-9, 2] > 0.99).all()
    assert_oriented_manifold_edges(faces)
    # Closed: every directed edge has its reverse.
    edges = {tuple(e) for f in faces for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))}
    assert all((b, a) in edges for a, b in edges)


def test_tipped_grid_faces_up_and_has_no_degenerate_triangles():
    rows, cols = 6, 5
    u = np.linspace(0, 1, rows)
    v = np.linspace(-1, 1, cols)
    width = np.sin(np.pi * u)
    grid = np.stack(np.broadcast_arrays(u[:, None], v[None] * width[:, None], 0 * v[None]), -1)
    vertices = np.concatenate([grid[0, :1], grid[1:-1].reshape(-1, 3), grid[-1, :1]])
    faces = tipped_grid_faces(rows, cols)
    normals, area, _ = face_normals(vertices, faces)
    assert area.min() > 1e-4
    np.testing.assert_allclose(normals, np.tile([0, 0, 1.0], (len(faces), 1)), atol=1e-12)
    assert_oriented_manifold_edges(faces)


def test_pot_and_soil_sit_at_the_soil_surface():
    shape = PotShape()
    rng = np.random.default_rng(0)
    pv, pf, pc = build_pot(shape, rng)
    sv, sf, sc = build_soil(shape, rng)
    assert pv[:, 2].min() == pytest.approx(-shape.depth)
    assert pv[:, 2].max() == pytest.approx(shape.rim_top)
    np.testing.assert_allclose(sv[:, 2], 0.0)
    assert np.hypot(sv[:, 0], sv[:, 1]).max() == pytest.approx(shape.soil_radius())
    soil_normals, soil_area, _ = face_normals(sv, sf)
    assert (soil_normals[:, 2] > 0.999).all()
    assert soil_area.sum() == pytest.approx(np.pi * shape.soil_radius() ** 2, rel=0.01)
    normals, area, centres = face_normals(pv, pf)
    assert area.min() > 1e-9
    # Below the rim band and above the bottom there is only the outer wall.
    outer = (centres[:, 2] > -shape.depth + 1e-6) & (centres[:, 2] < -shape.rim_height / 2)
    assert outer.sum() >= shape.segments
    radial = centres[outer] * np.array([1, 1, 0])
    assert (np.einsum("ij,ij->i", normals[outer], radial) > 0).all()  # outer wall faces out
    for colors in (pc, sc):
        assert colors.min() >= 0 and colors.max() <= 1
