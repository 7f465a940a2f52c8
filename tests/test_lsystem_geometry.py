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


def test_tube_survives_reversals_kinks_and_coincident_points():
    points = np.array(
        [[0, 0, 0], [0, 0, 1], [0, 0, 1 + 1e-9], [0, 0, 0.5], [0.5, 0, 0.5], [0.5, 0, 0.5]],
        dtype=float,
    )
    vertices, faces = tube(points, np.full(len(points), 0.05), 6)
    assert np.isfinite(vertices).all()
    loop, _ = tube(np.array([[0, 0, 0], [0, 0, 1], [0, 0, 0.0]]), np.full(3, 0.05), 6)
    assert np.isfinite(loop).all()
    _, area, _ = face_normals(vertices, faces)
    assert area.min() > 1e-8
    # The tip is where the polyline ends.
    np.testing.assert_allclose(vertices[-1][[0, 2]], [0.5 + 0.015, 0.5], atol=1e-9)


def test_random_turtle_strings_give_finite_valid_stems():
    from plantdreamer.lsystem.engine import LSystem
    from plantdreamer.lsystem.turtle import TurtleConfig, interpret

    rng = np.random.default_rng(0)
    symbols = ["F(0.05)", "F(1e-7)", "+(90)", "-(180)", "&(179.9)", "^(45)", "/(33)", "|", "$"]
    for _ in range(200):
        body = " ".join(rng.choice(symbols, size=12))
        string = f"F(0.1) {body} [ {' '.join(rng.choice(symbols, size=6))} F(0.02) ] F(0.01)"
        skeleton = interpret(LSystem(string, []).derive(0, rng), TurtleConfig(elasticity=3.0))
        for chain in skeleton.chains:
            if np.ptp(chain.points, axis=0).max() <= 1e-6:
                continue  # generate_plant skips these too
            vertices, faces = tube(chain.points, chain.radii, 5)
            assert np.isfinite(vertices).all()
            _, area, _ = face_normals(vertices, faces)
            assert area.min() > 0


def one_leaf(shape, length=0.1, heading=(1.0, 0.0, 0.0), floor=-1.0, seed=0):
    from plantdreamer.lsystem.organs import LeafBatch, build_leaves

    h = np.array([heading], dtype=float)
    h /= np.linalg.norm(h)
    left = np.cross([0.0, 0.0, 1.0], h[0])
    left /= np.linalg.norm(left)
    batch = LeafBatch(
        positions=np.zeros((1, 3)),
        headings=h,
        lefts=left[None],
        ups=np.cross(h[0], left)[None],
        lengths=np.array([length]),
        tones=np.zeros(1),
    )
    vertices, faces, colors = build_leaves(shape, batch, np.random.default_rng(seed), floor)
    return vertices[0], faces, colors[0]


def test_flat_leaf_has_the_outline_length_and_width():
    from plantdreamer.lsystem.organs import LeafShape

    shape = LeafShape(aspect=0.5, droop=0.0, curl=0.0, fold=0.0, cup=0.0)
    v, f, c = one_leaf(shape)
    np.testing.assert_allclose(v[:, 2], 0.0, atol=1e-12)
    assert v[:, 0].min() == pytest.approx(0.0) and v[:, 0].max() == pytest.approx(0.1)
    assert 0.9 * 0.05 <= np.ptp(v[:, 1]) <= 1.1 * 0.05  # width = aspect * length, +-10% jitter
    normals, area, _ = face_normals(v, f)
    assert (normals[:, 2] > 0.999).all() and area.min() > 1e-9
    assert c.min() >= 0 and c.max() <= 1


def test_droop_curl_fold_and_floor_shape_the_blade():
    from plantdreamer.lsystem.organs import LeafShape

    flat = dict(droop=0.0, curl=0.0, fold=0.0, cup=0.0)
    tip = lambda v: v[-1]  # noqa: E731 - the last vertex is the blade tip
    assert tip(one_leaf(LeafShape(**{**flat, "droop": 1.0}))[0])[2] < -0.02
    assert tip(one_leaf(LeafShape(**{**flat, "curl": 0.8}))[0])[2] > 0.02
    assert tip(one_leaf(LeafShape(**{**flat, "curl": -0.8}))[0])[2] < -0.02
    folded, _, _ = one_leaf(LeafShape(**{**flat, "fold": 0.3}))
    margin = np.abs(folded[:, 1]) > 0.01
    assert (folded[margin, 2] > 0).all()  # the halves rise from the midrib
    floored, _, _ = one_leaf(LeafShape(**{**flat, "droop": 3.0}), floor=-0.01)
    assert tip(floored)[2] >= -0.01 - 1e-12
    # Droop scales with how horizontal the midrib is: an upright leaf barely bends.
    upright, _, _ = one_leaf(LeafShape(**{**flat, "droop": 1.0}), heading=(1e-3, 0, 1))
    assert np.linalg.norm(tip(upright)[:2]) < 0.01


def test_serration_lobes_and_ruffle_change_the_margin():
    from plantdreamer.lsystem.organs import LeafShape

    u = np.linspace(0, 1, 401)
    plain = LeafShape().half_width(u)
    toothed = LeafShape(teeth=8, tooth_depth=0.2).half_width(u)
    assert (toothed <= plain + 1e-12).all()
    # One notch per tooth: the relative width has 8 local minima inside the blade.
    ratio = toothed[1:-1] / plain[1:-1]
    minima = np.sum((ratio[1:-1] < ratio[:-2]) & (ratio[1:-1] < ratio[2:]))
    assert 6 <= minima <= 9
    flat = dict(droop=0.0, curl=0.0, fold=0.0, cup=0.0)
    ruffled, _, _ = one_leaf(LeafShape(**flat, ruffle=0.05, ruffle_waves=6, rows=60, cols=9))
    assert np.ptp(ruffled[:, 2]) > 0.005


@pytest.mark.parametrize(
    "kwargs", [{"widest": 1.2}, {"aspect": 0}, {"cols": 8}, {"rows": 2}, {"tooth_depth": 1.0}]
)
def test_bad_leaf_shapes_are_rejected(kwargs):
    from plantdreamer.lsystem.organs import LeafShape

    with pytest.raises(InputError, match="LeafShape"):
        LeafShape(**kwargs)
