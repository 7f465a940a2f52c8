"""Label files read back by their own consumers: pycocotools for COCO, the documented YOLO-seg
format, Open3D (when installed) or plyfile for points.ply, nerfstudio's transforms.json keys."""

from __future__ import annotations

import json

import numpy as np
import pytest

from plantdreamer.errors import InputError
from plantdreamer.exports import split_plants, view_objects, write_plant_exports
from plantdreamer.exports.instances import MIN_INSTANCE_AREA
from plantdreamer.exports.points import read_class_names
from plantdreamer.exports.splits import parse_ratios
from plantdreamer.exports.yolo import mask_polygons

pycocotools = pytest.importorskip("pycocotools")


def read_png(path):
    import imageio.v3 as iio

    return np.asarray(iio.imread(path))


# --- objects of a view ------------------------------------------------------------------


def test_view_objects_filter_slivers_and_never_make_zero_size_boxes():
    semantic = np.zeros((8, 10), np.uint8)
    instance = np.zeros((8, 10), np.uint16)
    instance[1:4, 2:3] = 5  # a one-pixel-wide leaf of 3 pixels: id 4
    semantic[1:4, 2:3] = 1
    instance[4:8, 4:9] = 8  # id 7: 20 pixels, 12 of class 1, 8 of class 2
    semantic[4:8, 4:9] = 1
    semantic[6:8, 4:8] = 2
    objects = view_objects(semantic, instance, min_area=3)
    assert objects.instance_ids.tolist() == [4, 7]
    assert objects.categories.tolist() == [1, 1]
    assert objects.areas.tolist() == [3, 20]
    # Pixel-edge boxes: the one-column leaf is 1 wide, not 0.
    assert objects.boxes.tolist() == [[2, 1, 3, 4], [4, 4, 9, 8]]
    assert objects.masks.dtype == bool and objects.masks[1].sum() == 20
    filtered = view_objects(semantic, instance, min_area=4)
    assert filtered.instance_ids.tolist() == [7] and filtered.dropped == 1
    with pytest.raises(InputError, match="at least 1 pixel"):
        view_objects(semantic, instance, min_area=0)
    none = view_objects(semantic, instance, min_area=100)
    assert none.masks.shape == (0, 8, 10) and none.boxes.shape == (0, 4) and none.dropped == 2


def test_polygons_outline_each_piece_of_a_mask():
    mask = np.zeros((12, 12), bool)
    mask[2:6, 1:5] = True
    mask[8:11, 7:11] = True
    rings = mask_polygons(mask)
    assert len(rings) == 2
    xs = sorted((r[:, 0].min(), r[:, 0].max()) for r in rings)
    assert xs == [(1.0, 5.0), (7.0, 11.0)]  # pixel edges: columns 1..4 span x 1..5


# --- COCO -------------------------------------------------------------------------------


def test_coco_file_loads_in_pycocotools_and_masks_are_the_instance_pixels(bean):
    from pycocotools import mask as mask_utils
    from pycocotools.coco import COCO

    coco = COCO(str(bean / "coco.json"))
    meta = json.loads((bean / "transforms.json").read_text())
    assert {c["name"] for c in coco.loadCats(coco.getCatIds())} == {"leaf", "stem", "pot", "soil"}
    assert len(coco.getImgIds()) == len(meta["frames"])
    written = 0
    for image in coco.loadImgs(coco.getImgIds()):
        frame = next(f for f in meta["frames"] if f["file_path"] == image["file_name"])
        instance = read_png(bean / frame["instance_path"]).astype(np.int64)
        semantic = read_png(bean / frame["semantic_path"])
        assert (image["height"], image["width"]) == instance.shape
        anns = coco.loadAnns(coco.getAnnIds(imgIds=image["id"]))
        ids, areas = np.unique(instance[instance > 0] - 1, return_counts=True)
        kept = set(ids[areas >= MIN_INSTANCE_AREA].tolist())
        assert {a["instance_id"] for a in anns} == kept
        for ann in anns:
            mask = coco.annToMask(ann).astype(bool)
            np.testing.assert_array_equal(mask, instance == ann["instance_id"] + 1)
            assert ann["iscrowd"] == 0 and ann["area"] == mask.sum()
            w, h = ann["bbox"][2:]
            assert w >= 1 and h >= 1
            assert ann["category_id"] == np.bincount(semantic[mask]).argmax() == 1  # leaves
            assert mask_utils.area(ann["segmentation"]) == ann["area"]
            written += 1
    info = json.loads((bean / "coco.json").read_text())["info"]
    assert written == info["objects"] > 0
    assert info["min_instance_area"] == MIN_INSTANCE_AREA


def test_a_smaller_area_limit_writes_more_objects(bean, tmp_path):
    import shutil

    copy = shutil.copytree(bean, tmp_path / "copy")
    before = json.loads((copy / "coco.json").read_text())["info"]
    report = write_plant_exports(copy, min_area=1)
    assert report.dropped == 0
    assert report.objects == before["objects"] + before["objects_left_out"]


# --- YOLO -------------------------------------------------------------------------------


def parse_yolo_seg(label_file, nc):
    """Ultralytics' documented segment format: ``class x1 y1 x2 y2 ...``, normalised, at
    least three vertices, class below ``nc`` (docs.ultralytics.com/datasets/segment)."""
    polygons = []
    for line in label_file.read_text().splitlines():
        parts = line.split()
        cls, xy = int(parts[0]), np.array(parts[1:], dtype=np.float64)
        assert 0 <= cls < nc and xy.size % 2 == 0 and xy.size >= 6
        assert ((xy >= 0) & (xy <= 1)).all()
        polygons.append((cls, xy.reshape(-1, 2)))
    return polygons


def test_yolo_labels_follow_the_documented_layout_and_cover_the_masks(bean):
    import yaml
    from matplotlib.path import Path

    data = yaml.safe_load((bean / "yolo" / "data.yaml").read_text())
    assert data["nc"] == len(data["names"]) == 4 and data["names"][0] == "leaf"
    assert "path" not in data  # resolved against the yaml's folder
    images = sorted((bean / "yolo" / data["train"]).glob("*.png"))
    assert [p.name for p in images] == sorted(p.name for p in (bean / "renders").glob("*.png"))
    coco = json.loads((bean / "coco.json").read_text())
    for image in images:
        # Ultralytics' img2label_paths: the last /images/ becomes /labels/, suffix .txt.
        label = str(image).rsplit("/images/", 1)
        label_file = bean / "yolo" / "labels" / (image.stem + ".txt")
        assert label[0] + "/labels/" + image.stem + ".txt" == str(label_file)
        np.testing.assert_array_equal(read_png(image), read_png(bean / "renders" / image.name))
        assert image.stat().st_ino == (bean / "renders" / image.name).stat().st_ino  # a link
        polygons = parse_yolo_seg(label_file, data["nc"])
        h, w = read_png(image).shape[:2]
        # A pixel is inside when its centre is (the 0.5 level passes between centres).
        rows, cols = np.mgrid[0:h, 0:w]
        centres = np.c_[cols.reshape(-1) + 0.5, rows.reshape(-1) + 0.5]
        got = np.zeros(h * w, bool)
        for cls, xy in polygons:
            assert cls == 0  # only leaves have instances
            got |= Path(xy * [w, h]).contains_points(centres)
        got = got.reshape(h, w)
        img = next(i for i in coco["images"] if i["file_name"].endswith(image.name))
        objects = [a for a in coco["annotations"] if a["image_id"] == img["id"]]
        truth = np.zeros((h, w), bool)
        instance = read_png(bean / "instances" / image.name).astype(np.int64)
        for a in objects:
            truth |= instance == a["instance_id"] + 1
        # Equal but for holes in a leaf, which YOLO polygons do not represent.
        iou = (got & truth).sum() / max((got | truth).sum(), 1)
        assert iou > 0.97, iou


# --- splits -----------------------------------------------------------------------------


def test_splits_are_seeded_disjoint_and_by_plant():
    ids = [f"bean-{i:03d}" for i in range(20)]
    a = split_plants(ids, (0.6, 0.2, 0.2), seed=1)
    assert [len(a[s]) for s in ("train", "val", "test")] == [12, 4, 4]
    assert sorted(a["train"] + a["val"] + a["test"]) == ids
    assert split_plants(list(reversed(ids)), (0.6, 0.2, 0.2), seed=1) == a
    assert split_plants(ids, (0.6, 0.2, 0.2), seed=2) != a
    assert parse_ratios("8,1,1") == pytest.approx((0.8, 0.1, 0.1))
    for bad in ("0.8,0.2", "a,b,c", "0,0,0", "-1,1,1"):
        with pytest.raises(InputError, match="--split"):
            parse_ratios(bad)


# --- 3D ---------------------------------------------------------------------------------


def test_plant_ply_names_its_classes_and_loads_the_inria_way(bean):
    from plyfile import PlyData

    ply = PlyData.read(str(bean / "plant.ply"))
    names = [p.name for p in ply["vertex"].properties]
    # INRIA's load_ply asserts 3 * (3 + 1) ** 2 - 3 = 45 f_rest properties (its default degree).
    assert sum(n.startswith("f_rest_") for n in names) == 45
    assert names[-2:] == ["label", "instance"]
    assert read_class_names(bean / "plant.ply") == {1: "leaf", 2: "stem", 3: "pot", 4: "soil"}
    run = json.loads((bean / "run.json").read_text())
    assert run["class_names"] == {"1": "leaf", "2": "stem", "3": "pot", "4": "soil"}


def test_points_ply_has_colours_and_labels_for_point_cloud_readers(bean):
    from plyfile import PlyData

    from plantdreamer.io import read_splat_ply

    g = read_splat_ply(bean / "plant.ply")
    v = PlyData.read(str(bean / "points.ply"))["vertex"]
    assert [p.name for p in v.properties] == [
        "x", "y", "z", "red", "green", "blue", "label", "instance",
    ]  # fmt: skip
    assert v["red"].dtype == np.uint8
    np.testing.assert_array_equal(np.c_[v["x"], v["y"], v["z"]], g.means)
    np.testing.assert_array_equal(np.c_[v["label"], v["instance"]], g.labels)
    colours = np.c_[v["red"], v["green"], v["blue"]]
    assert colours.std() > 5  # real colours, not one grey
    assert read_class_names(bean / "points.ply")[1] == "leaf"


def test_open3d_reads_points_colours_and_labels(bean):
    o3d = pytest.importorskip("open3d")
    legacy = o3d.io.read_point_cloud(str(bean / "points.ply"))
    assert legacy.has_colors() and not legacy.has_normals()
    assert len(legacy.points) == len(legacy.colors) > 0
    tensor = o3d.t.io.read_point_cloud(str(bean / "points.ply"))
    labels = tensor.point["label"].numpy().reshape(-1)
    assert set(np.unique(labels)) == {1, 2, 3, 4}
    assert tensor.point["colors"].shape == (len(labels), 3)


def test_transforms_json_follows_nerfstudio_and_names_the_point_cloud(bean):
    """nerfstudio's format (docs.nerf.studio, "Data conventions"): OpenGL camera-to-world
    4x4 ``transform_matrix`` per frame, shared intrinsics, ``ply_file_path`` relative to
    the file, read by Open3D for splatfacto's initial points (needs colours)."""
    meta = json.loads((bean / "transforms.json").read_text())
    assert meta["ply_file_path"] == "points.ply" and (bean / meta["ply_file_path"]).is_file()
    for key in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
        assert key in meta
    from plantdreamer.io import read_splat_ply

    centre = read_splat_ply(bean / "plant.ply").means.mean(0)
    for frame in meta["frames"]:
        c2w = np.array(frame["transform_matrix"])
        assert c2w.shape == (4, 4) and np.allclose(c2w[3], [0, 0, 0, 1])
        np.testing.assert_allclose(c2w[:3, :3] @ c2w[:3, :3].T, np.eye(3), atol=1e-6)
        # OpenGL: the camera looks down its -z axis, towards the plant.
        to_plant = centre - c2w[:3, 3]
        assert np.dot(-c2w[:3, 2], to_plant / np.linalg.norm(to_plant)) > 0.8
        assert (bean / frame["file_path"]).is_file()
