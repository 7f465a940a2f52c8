"""Area-uniform surface sampling: chi-square on a known surface, attributes, seeds, errors."""

import numpy as np
import pytest

from plantdreamer.cloud import PointCloud
from plantdreamer.errors import InputError
from plantdreamer.lsystem import OrganClass, PlantMesh, generate_plant, sample_points


def square_mesh():
    """The unit square at z = 0 as a fan around an off-centre point: four triangles of very
    different areas (0.05, 0.05, 0.45, 0.45), so ignoring areas would show."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.9, 0.1, 0]], np.float32)
    faces = np.array([[4, 0, 1], [4, 1, 2], [4, 2, 3], [4, 3, 0]], dtype=np.int64)  # CCW from +z
    colors = np.stack([vertices[:, 0], vertices[:, 1], np.zeros(5, np.float32)], axis=1)
    labels = np.full(5, OrganClass.SOIL, dtype=np.int32)
    return PlantMesh(vertices, faces, colors, labels, np.full(5, -1, dtype=np.int32))


def chi_square_quantile(k, z):
    """Wilson-Hilferty approximation of the chi-square quantile with k degrees of freedom at
    the standard normal quantile z (accurate to < 1% for k ~ 100)."""
    h = 2.0 / (9.0 * k)
    return k * (1.0 - h + z * np.sqrt(h)) ** 3


def chi_square_uniform(xy, bins=10):
    counts, _, _ = np.histogram2d(xy[:, 0], xy[:, 1], bins=bins, range=[[0, 1], [0, 1]])
    expected = len(xy) / bins**2
    return float(((counts - expected) ** 2 / expected).sum())


# p = 1e-4 upper tail of chi-square with 99 degrees of freedom (z = 3.719).
CRITICAL = chi_square_quantile(99, 3.719)


def test_critical_value_is_the_tabulated_one():
    assert CRITICAL == pytest.approx(160.1, abs=1.0)  # tables: 160.1 at p = 1e-4, df = 99


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_points_are_uniform_over_a_known_surface(seed):
    cloud = sample_points(square_mesh(), n=200_000, seed=seed)
    assert chi_square_uniform(cloud.positions) < CRITICAL


def test_the_chi_square_check_rejects_a_sampler_that_ignores_area():
    # Negative control: same barycentric sampling, but faces picked uniformly.
    mesh = square_mesh()
    rng = np.random.default_rng(0)
    n = 200_000
    face = rng.integers(0, len(mesh.faces), n)
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    w = np.stack([1 - r1, r1 * (1 - r2), r1 * r2], axis=1)
    xy = np.einsum("nk,nkd->nd", w, mesh.vertices[mesh.faces[face]])
    assert chi_square_uniform(xy) > 10 * CRITICAL


def test_points_carry_colour_normal_and_labels_of_their_face():
    cloud = sample_points(square_mesh(), n=5000, seed=3)
    assert isinstance(cloud, PointCloud)
    assert cloud.positions.dtype == np.float32 and cloud.normals.dtype == np.float32
    np.testing.assert_allclose(cloud.normals, np.tile([0, 0, 1], (5000, 1)))
    # Colour is (x, y, 0) at the vertices and interpolated linearly in between.
    np.testing.assert_allclose(cloud.colors[:, :2], cloud.positions[:, :2], atol=1e-6)
    assert cloud.attributes["label"].dtype == np.int32
    assert (cloud.attributes["label"] == OrganClass.SOIL).all()
    assert (cloud.attributes["instance"] == -1).all()


def test_boundary_distance_of_the_square():
    mesh = square_mesh()
    # Corners lie on the outline; the fan's centre (0.9, 0.1) is 0.1 from two sides.
    np.testing.assert_allclose(mesh.boundary_distance(), [0, 0, 0, 0, 0.1], atol=1e-7)
    cloud = sample_points(mesh, n=2000, seed=1, boundary_distance=True)
    d = cloud.attributes["boundary_distance"]
    assert d.dtype == np.float32 and (0 <= d).all() and (d <= 0.1 + 1e-7).all()
    x, y = cloud.positions[:, 0], cloud.positions[:, 1]
    # Interpolated from the corners: 0.1 times the weight of the centre vertex, so 0 on the
    # square's sides and never above the true distance near the centre's two close sides.
    assert (d <= np.minimum(1 - x, y) + 1e-6).all()
    assert "boundary_distance" not in sample_points(mesh, n=10, seed=1).attributes


def test_plant_labels_are_sampled_in_proportion_to_area():
    mesh = generate_plant("bean", 4)
    cloud = sample_points(mesh, n=100_000, seed=0)
    areas, _ = mesh.face_areas_normals()
    face_label = mesh.labels[mesh.faces[:, 0]]
    for organ in OrganClass:
        share = areas[face_label == organ].sum() / areas.sum()
        got = (cloud.attributes["label"] == organ).mean()
        assert got == pytest.approx(share, abs=5 * np.sqrt(share * (1 - share) / 1e5) + 1e-4)
    leaf = cloud.attributes["label"] == OrganClass.LEAF
    assert (cloud.attributes["instance"][leaf] >= 0).all()
    assert (cloud.attributes["instance"][~leaf] == -1).all()
    assert set(np.unique(cloud.attributes["instance"][leaf])) == set(range(mesh.n_leaves))
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=1e-5)
    assert np.isfinite(cloud.positions).all()


def test_same_seed_same_points_other_seed_other_points():
    mesh = generate_plant("kale", 0)
    a, b = sample_points(mesh, 1000, seed=5), sample_points(mesh, 1000, seed=5)
    c = sample_points(mesh, 1000, seed=6)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.colors, b.colors)
    assert not np.array_equal(a.positions, c.positions)


@pytest.mark.parametrize(("n", "seed"), [(0, 0), (-5, 0), (2.5, 0), (10, -1)])
def test_bad_arguments_are_input_errors(n, seed):
    with pytest.raises(InputError):
        sample_points(square_mesh(), n=n, seed=seed)


def test_a_mesh_without_area_cannot_be_sampled():
    mesh = square_mesh()
    mesh.vertices[:, 1] = 0.0  # everything collapses onto a line
    with pytest.raises(InputError, match="no surface area"):
        sample_points(mesh, 10)
