"""The 3-D traits against independent computations: an L-System plant's leaf areas, height
and canopy by trimesh and SciPy on the same mesh faces, its midribs and rows read off the
mesh's own vertices; a scan's and the Gaussians' figures by numpy on the points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plantdreamer.lsystem import OrganClass, grow, list_species
from plantdreamer.traits.plant import plant_traits
from plantdreamer.traits.points import gaussian_traits, scan_traits
from plantdreamer.traits.shapes import canopy, convex_hull_2d, diameter, polygon_area

trimesh = pytest.importorskip("trimesh")
spatial = pytest.importorskip("scipy.spatial")


@pytest.fixture(scope="module", params=list_species())
def plant(request):
    return grow(request.param, 2)


def test_leaf_areas_count_and_height_are_trimeshs(plant):
    traits = plant_traits(plant)
    mesh = plant.mesh
    whole = mesh.to_trimesh()
    face_label = mesh.labels[mesh.faces[:, 0]]
    face_instance = mesh.instances[mesh.faces[:, 0]]
    ids = np.unique(face_instance[face_label == OrganClass.LEAF])
    assert traits["plant"]["leaf_count"] == len(ids) == len(traits["leaves"])
    assert [leaf["instance"] for leaf in traits["leaves"]] == ids.tolist()
    # Every leaf's area: trimesh's face areas summed by instance.
    by_instance = np.bincount(face_instance[face_instance >= 0],
                              weights=whole.area_faces[face_instance >= 0])  # fmt: skip
    np.testing.assert_allclose([leaf["area"] for leaf in traits["leaves"]], by_instance[ids],
                               rtol=1e-12)  # fmt: skip
    for leaf in traits["leaves"][:: max(1, len(ids) // 8)]:  # 8 leaves whole, by submesh
        faces = np.flatnonzero(face_instance == leaf["instance"])
        part = whole.submesh([faces], append=True)
        assert leaf["area"] == pytest.approx(part.area, rel=1e-12, abs=0)
        # Centroid and extent of the leaf's surface (trimesh: area-weighted triangles).
        surface = (part.triangles_center * part.area_faces[:, None]).sum(axis=0) / part.area
        np.testing.assert_allclose(leaf["centroid"], surface, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(leaf["extent"], part.extents, rtol=1e-6, atol=1e-9)
    leaf_faces = np.flatnonzero(face_label == OrganClass.LEAF)
    total = whole.submesh([leaf_faces], append=True).area
    assert traits["plant"]["leaf_area"] == pytest.approx(total, rel=1e-12)
    plant_faces = np.flatnonzero(np.isin(face_label, [OrganClass.LEAF, OrganClass.STEM]))
    body = whole.submesh([plant_faces], append=True)
    assert traits["plant"]["height"] == pytest.approx(body.bounds[1][2], rel=1e-7)
    hull = spatial.ConvexHull(body.vertices[:, :2])
    assert traits["plant"]["canopy_hull_area"] == pytest.approx(hull.volume, rel=1e-9)
    corners = body.vertices[hull.vertices, :2]
    width = spatial.distance.pdist(corners).max()
    assert traits["plant"]["canopy_width"] == pytest.approx(width, rel=1e-9)


def test_midrib_length_width_and_angles_from_the_mesh_vertices(plant):
    traits = plant_traits(plant)
    shape = next(iter(plant.species.leaves.values()))
    rows, cols = shape.rows, shape.cols
    normals = plant.mesh.to_trimesh().face_normals
    face_instance = plant.mesh.instances[plant.mesh.faces[:, 0]]
    areas = plant.mesh.to_trimesh().area_faces
    for leaf in traits["leaves"][:12]:
        v = plant.mesh.vertices[plant.mesh.instances == leaf["instance"]].astype(np.float64)
        grid = v[1:-1].reshape(rows - 2, cols, 3)  # base tip, inner rows, far tip
        midrib = np.vstack([v[:1], grid[:, cols // 2], v[-1:]])
        length = np.linalg.norm(np.diff(midrib, axis=0), axis=1).sum()
        assert leaf["length"] == pytest.approx(length, rel=1e-6)
        width = max(np.linalg.norm(np.diff(row, axis=0), axis=1).sum() for row in grid)
        assert leaf["width"] == pytest.approx(width, rel=1e-6)
        faces = face_instance == leaf["instance"]
        n = (normals[faces] * areas[faces, None]).sum(axis=0)
        zenith = math.degrees(math.acos(n[2] / np.linalg.norm(n)))
        assert leaf["inclination"] == pytest.approx(zenith, abs=1e-4)
        chord = midrib[-1] - midrib[0]
        assert leaf["azimuth"] == pytest.approx(math.degrees(math.atan2(chord[1], chord[0])) % 360,
                                                abs=1e-4)  # fmt: skip
        assert leaf["base"] == pytest.approx(v[0].tolist(), abs=1e-7)
        assert leaf["node_height"] <= leaf["base_height"] + 1e-9


def test_stems_and_nodes_follow_the_skeleton():
    bean, mint = grow("bean", 0), grow("mint", 1)
    assert plant_traits(bean)["plant"]["stem_count"] == 1
    traits = plant_traits(mint)
    shoots = {leaf["shoot"] for leaf in traits["leaves"]}
    assert traits["plant"]["stem_count"] == len(shoots) >= 3
    # A bean leaflet's node is where its petiole leaves the main stem (or a branch).
    chains = bean.skeleton.chains
    for leaf in plant_traits(bean)["leaves"]:
        stem = chains[leaf["stem"]]
        gap = np.linalg.norm(stem.points - np.array(leaf["node"]), axis=1).min()
        assert gap < 1e-9 and leaf["shoot"] == 0


def test_growth_fields_and_new_leaves():
    young, old = grow("bean", 0, 0.5), grow("bean", 0, 0.75)
    traits = plant_traits(old, since=0.5)
    assert traits["plant"]["growth"] == {"stage": 0.75, "steps": 8, "since": 0.5}
    before = {b.instance for b in young.blades}
    new = {leaf["instance"] for leaf in traits["leaves"] if leaf["new"]}
    assert new == {leaf["instance"] for leaf in traits["leaves"]} - before and new


def test_a_scans_traits_are_numpys_on_its_points():
    rng = np.random.default_rng(3)
    positions = rng.normal(size=(600, 3)) * [0.2, 0.1, 0.3] + [5.0, -2.0, 10.0]
    labels = np.stack([rng.choice([7, 8, 9], 600), rng.choice([-1, 70001, 70004], 600)], 1)
    names = {7: "leaf", 8: "stem", 9: "pot"}
    traits = scan_traits(positions, labels, names)
    plant = np.isin(labels[:, 0], [7, 8])
    p = positions[plant]
    assert traits["plant"]["height"] == pytest.approx(np.ptp(p[:, 2]))
    hull = spatial.ConvexHull(p[:, :2])
    assert traits["plant"]["canopy_hull_area"] == pytest.approx(hull.volume)
    leaf = (labels[:, 0] == 7) & (labels[:, 1] >= 0)
    assert traits["plant"]["leaf_count"] == len(np.unique(labels[leaf, 1])) == 2
    for record in traits["leaves"]:
        mine = positions[leaf & (labels[:, 1] == record["instance"])]
        assert record["count"] == len(mine)
        np.testing.assert_allclose(record["centroid"], mine.mean(axis=0))
        np.testing.assert_allclose(record["extent"], np.ptp(mine, axis=0))
    # Unnamed classes: every instance is a leaf and every class the plant.
    unnamed = scan_traits(positions, labels, None)
    assert unnamed["plant"]["leaf_count"] == 2 and unnamed["plant"]["points"] == 600


def test_the_gaussians_figures_by_class_and_leaf():
    rng = np.random.default_rng(4)
    means = rng.uniform(-0.1, 0.4, size=(300, 3))
    labels = np.stack([rng.choice([1, 2, 4], 300), np.full(300, -1)], 1)
    labels[labels[:, 0] == 1, 1] = rng.choice([0, 3], int((labels[:, 0] == 1).sum()))
    names = {1: "leaf", 2: "stem", 4: "soil"}
    g = gaussian_traits(means, labels, names, ground=0.0)
    plant = labels[:, 0] != 4
    assert g["plant"]["height"] == pytest.approx(means[plant, 2].max())
    assert g["plant"]["count"] == plant.sum()
    assert set(g["classes"]) == {"leaf", "stem", "soil"}
    np.testing.assert_allclose(g["classes"]["stem"]["centroid"], means[labels[:, 0] == 2].mean(0))
    assert [leaf["instance"] for leaf in g["leaves"]] == [0, 3]


@pytest.mark.parametrize("kind", ["gauss", "grid", "line", "few", "duplicates"])
def test_the_convex_hull_is_scipys(kind):
    rng = np.random.default_rng(7)
    points = {
        "gauss": rng.normal(size=(5000, 2)),
        "grid": rng.integers(0, 6, size=(3000, 2)).astype(float),
        "line": np.c_[np.arange(200.0), 2 * np.arange(200.0)],
        "few": rng.normal(size=(3, 2)),
        "duplicates": np.repeat(rng.normal(size=(4, 2)), 100, axis=0),
    }[kind]
    hull = convex_hull_2d(points)
    if kind == "line":
        assert polygon_area(hull) == 0.0
        assert diameter(hull) == pytest.approx(math.hypot(199, 398))
        return
    reference = spatial.ConvexHull(points)
    assert len(hull) == len(reference.vertices)
    assert polygon_area(hull) == pytest.approx(reference.volume, rel=1e-12)
    ends = points[reference.vertices]
    assert diameter(hull) == pytest.approx(spatial.distance.pdist(ends).max(), rel=1e-12)
    width, area = canopy(np.c_[points, np.zeros(len(points))])
    assert (width, area) == (diameter(hull), polygon_area(hull))


def test_a_generated_scans_traits_come_from_its_labelled_points(tmp_path):
    """A scan (a bean's labelled samples, in millimetres far from the origin) through
    generate: traits.json's plant and leaves are numpy's on the scan's points."""
    import json

    from plantdreamer.io import write_ply
    from plantdreamer.lsystem import generate_plant, sample_points
    from plantdreamer.pipeline import GenerateConfig, generate_plants

    cloud = sample_points(generate_plant("bean", 4), 3000, seed=1)
    cloud.positions = (cloud.positions.astype(np.float64) * 1000 + [200.0, -50.0, 30.0]).astype(
        np.float32
    )
    write_ply(tmp_path / "scan.ply", cloud)
    cfg = GenerateConfig.of(pointcloud=str(tmp_path / "scan.ply"), guidance="none", steps=0,
                            points=0, sor_std=100.0, resolution=32, eval_views=1,
                            turntable="none")  # fmt: skip
    generate_plants([cfg], tmp_path / "o", show_progress=False)
    traits = json.loads((tmp_path / "o" / "traits.json").read_text())
    assert traits["source"] == "labelled points" and "scan's own frame" in traits["frame"]
    p = cloud.positions.astype(np.float64)
    label, instance = cloud.attributes["label"], cloud.attributes["instance"]
    # No class names: every class is the plant, every instance a leaf.
    assert traits["plant"]["leaf_count"] == len(np.unique(instance[instance >= 0]))
    assert traits["plant"]["height"] == pytest.approx(np.ptp(p[:, 2]), rel=1e-6)
    hull = spatial.ConvexHull(p[:, :2])
    assert traits["plant"]["canopy_hull_area"] == pytest.approx(hull.volume, rel=1e-5)
    for leaf in traits["leaves"][:6]:
        mine = p[instance == leaf["instance"]]
        assert leaf["count"] == len(mine)
        np.testing.assert_allclose(leaf["centroid"], mine.mean(axis=0), rtol=1e-6)
        np.testing.assert_allclose(leaf["extent"], np.ptp(mine, axis=0), rtol=1e-5, atol=1e-6)
    assert traits["gaussians"]["plant"]["count"] == len(p)
    assert set(traits["gaussians"]["classes"]) == {f"class {c}" for c in np.unique(label)}
    # Millimetres per pixel, at the scan's scale (a 32 px view of a plant ~400 mm tall).
    assert 5 < traits["views"][0]["metres_per_pixel"] < 100
