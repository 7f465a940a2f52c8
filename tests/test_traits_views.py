"""Per-view traits: a leaf half hidden by another measures half visible; the figures of
written views are PlantCV's size analysis of their plant masks and the COCO files' leaf
objects; traits.json holds the mesh's and the Gaussians' figures of the generated plant."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from plantdreamer.cameras import orbit, stack
from plantdreamer.gaussians import Gaussians
from plantdreamer.lsystem import grow
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.truth.ground_truth import GroundTruthRenderer, Splats
from plantdreamer.pipeline.truth.label_channels import LabelSet
from plantdreamer.rasterizer import rasterization
from plantdreamer.traits import map_figures
from plantdreamer.traits.plant import plant_traits
from plantdreamer.traits.record import view_recorder

NAMES = {1: "leaf", 2: "stem", 3: "pot", 4: "soil"}


def plate(y0: float, x: float, instance: int, n: int = 40, size: float = 1.0) -> Gaussians:
    """A square leaf of n x n flat Gaussians in the plane x = const, facing +x, spanning
    y0..y0 + size and -size/2..size/2 in z."""
    step = size / n
    ys, zs = np.meshgrid(y0 + step * (np.arange(n) + 0.5), step * (np.arange(n) + 0.5) - size / 2)
    means = np.stack([np.full(n * n, x), ys.ravel(), zs.ravel()], axis=1).astype(np.float32)
    scales = np.tile(np.log([step * 0.02, step * 0.7, step * 0.7]), (n * n, 1))
    return Gaussians(
        means=means,
        quats=np.tile([1.0, 0.0, 0.0, 0.0], (n * n, 1)).astype(np.float32),
        log_scales=scales.astype(np.float32),
        opacity_logits=np.full(n * n, 6.0, np.float32),
        sh=np.zeros((n * n, 1, 3), np.float32),
        labels=np.tile([1, instance], (n * n, 1)).astype(np.int32),
    )


def joined(*parts: Gaussians) -> Gaussians:
    fields = ("means", "quats", "log_scales", "opacity_logits", "sh", "labels")
    return Gaussians(**{f: np.concatenate([getattr(p, f) for p in parts]) for f in fields})


def test_a_leaf_half_hidden_by_another_is_half_visible():
    # The camera on +x; leaf 7 at x = 0, leaf 9 in front of its half y > 0 (and beyond it).
    g = joined(plate(-0.5, 0.0, 7), plate(0.0, 0.6, 9))
    model = GaussianModel(g)
    camera = orbit(4.0, 0.0, 0.0, 40.0, 160, 160)
    label_set = LabelSet.of(g.labels)
    _, _, meta = model.render([camera], 0.0)
    gt = GroundTruthRenderer(model, label_set)(camera, meta)
    ids = np.r_[label_set.instances, -1][gt.instance]
    splats = Splats.of(model)
    recorder = view_recorder(g.means, g.labels, NAMES, 1.0)
    recorder.add("view_000", camera, ids, meta)
    (record,) = recorder.views
    (alone_7, visible_7), (alone_9, visible_9) = record["leaves"]["7"], record["leaves"]["9"]
    assert visible_7 / alone_7 == pytest.approx(0.5, abs=0.04)
    assert visible_9 / alone_9 > 0.97
    # The alone silhouette is the full frame's render of leaf 7's Gaussians alone.
    mine = g.labels[:, 1] == 7
    viewmats, ks = stack([camera])
    _, alpha, _ = rasterization(splats.means[mine], splats.quats[mine], splats.scales[mine],
                                splats.opacities[mine], torch.ones((int(mine.sum()), 1)),
                                torch.from_numpy(viewmats), torch.from_numpy(ks), 160, 160,
                                tile_size=16)  # fmt: skip
    silhouette = alpha[0, ..., 0].numpy() >= 0.5
    assert alone_7 == silhouette.sum() and visible_7 == (silhouette & (ids == 7)).sum()
    # Metres per pixel at the plant's centre: depth over the focal length (scale 1).
    centre = g.means.astype(np.float64).mean(axis=0)
    assert record["metres_per_pixel"] == pytest.approx((4.0 - centre[0]) / camera.K[0, 0])


def test_leaves_sharing_a_render_are_each_alone_as_in_a_render_of_their_own():
    """Leaves whose tiles never meet share one render: each leaf's figures are those of a
    full-frame render of its Gaussians alone (a bean's 30-odd leaves, 2 views)."""
    from plantdreamer.pipeline import GenerateConfig
    from plantdreamer.pipeline.model.source import initial_gaussians, load_source
    from plantdreamer.traits.occlusion import LeafOcclusion

    cfg = GenerateConfig.of(species="bean", seed=1, points=4000)
    source = load_source(cfg.source, cfg.seed, surface=True)
    g = initial_gaussians(cfg.init, source, cfg.seed)
    model, label_set = GaussianModel(g), LabelSet.of(g.labels)
    splats = Splats.of(model)
    occlusion = LeafOcclusion(g.labels[:, 1], g.labels[:, 0] == 1)
    for azimuth in (0.0, 130.0):
        camera = orbit(4.0, 15.0, azimuth, 70.0, 192, 160)
        _, _, meta = model.render([camera], 0.0)
        gt = GroundTruthRenderer(model, label_set)(camera, meta)
        ids = np.r_[label_set.instances, -1][gt.instance]
        record = occlusion.view(ids, meta["state"])
        assert len(record) > 20 and set(record) == set(np.unique(ids[ids >= 0]).tolist())
        viewmats, ks = stack([camera])
        for leaf, (alone, visible) in record.items():
            mine = g.labels[:, 1] == leaf
            _, alpha, _ = rasterization(splats.means[mine], splats.quats[mine],
                                        splats.scales[mine], splats.opacities[mine],
                                        torch.ones((int(mine.sum()), 1)),
                                        torch.from_numpy(viewmats), torch.from_numpy(ks),
                                        192, 160, tile_size=16)  # fmt: skip
            silhouette = alpha[0, ..., 0].numpy() >= 0.5
            assert [alone, visible] == [silhouette.sum(), (silhouette & (ids == leaf)).sum()]
        # Some leaves are partly hidden, and none shows more of itself than it has.
        assert any(v < a for a, v in record.values())


def test_group_coverage_names_its_bad_arrays():
    from plantdreamer import _core
    from plantdreamer.errors import InputError

    camera = orbit(4.0, 0.0, 0.0, 40.0, 24, 16)
    viewmats, ks = stack([camera])
    n = 5
    scene = {"means": np.zeros((n, 3), np.float32), "quats": np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
             "scales": np.full((n, 3), 0.1, np.float32), "opacities": np.full(n, 0.9, np.float32),
             "colors": np.ones((n, 1), np.float32), "viewmats": viewmats, "Ks": ks, "width": 24,
             "height": 16}  # fmt: skip
    (out,) = _core.rasterize_forward_many([scene])
    ok = {"groups": np.zeros(n, np.int32), "labels": np.zeros((16, 24), np.int32),
          "group_labels": np.zeros(1, np.int32)}  # fmt: skip
    alone, visible = _core.group_coverage(out["state"], **ok, alpha_threshold=0.5)
    assert alone[0] == (out["alpha"] >= 0.5).sum() > 0 and visible[0] == alone[0]
    bad = [({"groups": np.zeros(n, np.int64)}, "groups must be a numpy array of int32"),
           ({"groups": np.zeros(n - 1, np.int32)}, "groups has 4 entries for 5 Gaussians"),
           ({"groups": np.full(n, -2, np.int32)}, "group -2 is neither -1"),
           ({"groups": np.ones(n, np.int32)}, "group 1 is neither -1"),
           ({"labels": np.zeros((24, 16), np.int32)}, r"labels must have shape \[16, 24\]"),
           ({"labels": np.zeros((16, 24), np.int64)}, "labels must be a numpy array of int32")]  # fmt: skip
    for change, message in bad:
        with pytest.raises(InputError, match=message):
            _core.group_coverage(out["state"], **{**ok, **change}, alpha_threshold=0.5)
    with pytest.raises(InputError, match="alpha threshold"):
        _core.group_coverage(out["state"], **ok, alpha_threshold=1.5)
    with pytest.raises(InputError, match="camera 1 of a pass of 1"):
        _core.group_coverage(out["state"], **ok, alpha_threshold=0.5, camera=1)
    with pytest.raises(TypeError):
        _core.group_coverage(scene, **ok, alpha_threshold=0.5)  # not a pass's state


def test_map_figures_count_leaves_by_area_and_measure_the_plant():
    semantic = np.zeros((20, 30), np.uint8)
    instance = np.zeros((20, 30), np.uint16)
    semantic[2:10, 3:9], instance[2:10, 3:9] = 1, 1  # leaf id 0: 48 px
    semantic[12:14, 20:22], instance[12:14, 20:22] = 1, 2  # leaf id 1: 4 px
    semantic[5:18, 12:13] = 2  # a stem: 13 px
    semantic[18:20, 0:30] = 4  # soil: not the plant
    figures = map_figures(semantic, instance, np.array([1, 2]), np.array([1]), min_area=5)
    assert figures == {"leaf_count": 1, "plant_area_px": 48 + 4 + 13, "plant_height_px": 16,
                       "plant_width_px": 19}  # fmt: skip
    assert map_figures(semantic, instance, np.array([1, 2]), None, min_area=4)["leaf_count"] == 2


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def plant_masks(bean):
    """Each written view's COCO image record, counts.csv row and plant mask (leaf and stem
    pixels of its class map)."""
    import imageio.v3 as iio

    coco = json.loads((bean / "coco.json").read_text())
    counts = rows(bean / "counts.csv")
    meta = json.loads((bean / "transforms.json").read_text())
    plant_values = [c["value"] for c in meta["semantic_classes"] if c["name"] in ("leaf", "stem")]
    assert len(counts) == len(coco["images"]) == 3
    for image, row in zip(coco["images"], counts, strict=True):
        assert row["file_name"] == image["file_name"]
        semantic = iio.imread(bean / meta["frames"][image["id"] - 1]["semantic_path"])
        yield image, row, np.isin(semantic, plant_values)


def test_written_views_count_cocos_leaf_objects(bean):
    from pycocotools.coco import COCO

    coco = COCO(str(bean / "coco.json"))
    leaf_category = next(c["id"] for c in coco.dataset["categories"] if c["name"] == "leaf")
    min_area = coco.dataset["info"]["min_instance_area"]
    traits = json.loads((bean / "traits.json").read_text())
    for image, row, mask in plant_masks(bean):
        leaves = coco.loadAnns(coco.getAnnIds(imgIds=image["id"], catIds=[leaf_category],
                                              iscrowd=False))  # fmt: skip
        assert image["leaf_count"] == int(row["leaf_count"]) == len(leaves) > 0
        assert all(a["area"] >= min_area for a in leaves)
        assert image["plant_area_px"] == int(row["plant_area_px"]) == mask.sum()
        assert float(row["metres_per_pixel"]) == image["metres_per_pixel"] > 0
        # Each leaf object's visible fraction is traits.json's record of the view.
        view = next(v for v in traits["views"] if v["file_path"] == image["file_name"])
        for a in coco.loadAnns(coco.getAnnIds(imgIds=image["id"], catIds=[leaf_category])):
            alone, visible = view["leaves"][str(a["instance_id"])]
            assert a["visible_fraction"] == visible / alone


@pytest.mark.slow  # importing PlantCV takes 5-15 s
def test_written_views_are_plantcvs_size_analysis(bean):
    pcv = pytest.importorskip("plantcv.plantcv")
    for image, row, mask in plant_masks(bean):
        white = mask.astype(np.uint8) * 255
        pcv.outputs.clear()
        pcv.params.debug = None
        pcv.analyze.size(img=np.dstack([white] * 3), labeled_mask=white, n_labels=1)
        seen = pcv.outputs.observations["default_1"]
        for name, key in (("area", "plant_area_px"), ("height", "plant_height_px"),
                          ("width", "plant_width_px")):  # fmt: skip
            assert seen[name]["value"] == image[key] == int(row[key]) > 0


def test_traits_json_holds_the_mesh_gaussians_and_views(bean):
    traits = json.loads((bean / "traits.json").read_text())
    run = json.loads((bean / "run.json").read_text())
    expected = plant_traits(grow("bean", run["config"]["seed"]))
    assert traits["source"] == "mesh and skeleton"
    for key in ("leaf_count", "leaf_area", "height", "canopy_width", "stem_count"):
        assert traits["plant"][key] == expected["plant"][key]
    assert [leaf["area"] for leaf in traits["leaves"]] == [
        leaf["area"] for leaf in expected["leaves"]
    ]
    # The Gaussians' figures: numpy on plant.ply (read by plyfile).
    plyfile = pytest.importorskip("plyfile")
    vertex = plyfile.PlyData.read(str(bean / "plant.ply"))["vertex"]
    xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1).astype(np.float64)
    label, instance = np.asarray(vertex["label"]), np.asarray(vertex["instance"])
    plant = np.isin(label, [1, 2])
    assert traits["gaussians"]["plant"]["height"] == pytest.approx(xyz[plant, 2].max(), abs=1e-6)
    for leaf in traits["gaussians"]["leaves"][:5]:
        mine = xyz[(label == 1) & (instance == leaf["instance"])]
        np.testing.assert_allclose(leaf["centroid"], mine.mean(axis=0), atol=1e-6)
        np.testing.assert_allclose(leaf["extent"], np.ptp(mine, axis=0), atol=1e-6)
    # Views: one record per render; the metres per pixel from transforms.json's cameras.
    meta = json.loads((bean / "transforms.json").read_text())
    assert [v["file_path"] for v in traits["views"]] == [f["file_path"] for f in meta["frames"]]
    centre = xyz[plant].mean(axis=0)
    for view, frame in zip(traits["views"], meta["frames"], strict=True):
        c2w = np.array(frame["transform_matrix"])
        depth = (centre - c2w[:3, 3]) @ -c2w[:3, 2]  # OpenGL: the camera looks along -z
        focal = (meta["fl_x"] + meta["fl_y"]) / 2
        assert view["metres_per_pixel"] == pytest.approx(depth / focal, rel=1e-5)
        for alone, visible in view["leaves"].values():
            assert 0 <= visible <= alone


def test_the_torch_targets_carry_the_views_traits(bean):
    v2 = pytest.importorskip("torchvision.transforms.v2")
    from plantdreamer.data import PlantViews

    coco = json.loads((bean / "coco.json").read_text())
    counts = rows(bean / "counts.csv")
    views = PlantViews(bean)
    half = PlantViews(bean, transforms=v2.Resize(48, interpolation=v2.InterpolationMode.NEAREST))
    for k, (row, image) in enumerate(zip(counts, coco["images"], strict=True)):
        _, target = views[k]
        assert target["leaf_count"] == int(row["leaf_count"])
        assert target["metres_per_pixel"] == float(row["metres_per_pixel"])
        fractions = {a["instance_id"]: a.get("visible_fraction", np.nan)
                     for a in coco["annotations"] if a["image_id"] == image["id"]}  # fmt: skip
        got = target["visible_fraction"].tolist()
        want = [fractions[int(i)] if int(i) >= 0 else np.nan for i in target["instance_ids"]]
        np.testing.assert_allclose(got, want, rtol=1e-6)
        _, small = half[k]
        plant = np.isin(np.asarray(small["semantic"]), [1, 2])
        assert small["plant_area_px"] == plant.sum() < target["plant_area_px"]
        assert small["leaf_count"] == target["leaf_count"]


@pytest.mark.slow  # a small generate
def test_without_leaf_occlusion_the_views_have_no_visible_fractions(tmp_path):
    from labelled_plant import make_plant

    plant = make_plant(tmp_path / "p", leaf_occlusion=False)
    traits = json.loads((plant / "traits.json").read_text())
    assert traits["views"] and all("leaves" not in v for v in traits["views"])
    assert all(v["metres_per_pixel"] > 0 for v in traits["views"])
    coco = json.loads((plant / "coco.json").read_text())
    assert coco["annotations"] and not any("visible_fraction" in a for a in coco["annotations"])
    assert all(image["leaf_count"] >= 0 for image in coco["images"])
