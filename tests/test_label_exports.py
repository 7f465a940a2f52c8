"""Label files read back by their own consumers: pycocotools for COCO, the documented YOLO-seg
format, Open3D (when installed) or plyfile for points.ply, nerfstudio's transforms.json keys."""

from __future__ import annotations

import hashlib
import json
import re

import numpy as np
import pytest

from plantdreamer.errors import InputError
from plantdreamer.exports import (
    split_plants,
    view_objects,
    write_dataset_exports,
    write_plant_exports,
)
from plantdreamer.exports.instances import MIN_INSTANCE_AREA
from plantdreamer.exports.pieces import label_pieces
from plantdreamer.exports.points import read_class_names
from plantdreamer.exports.splits import (
    SPLITS,
    check_splits,
    parse_ratios,
    species_counts,
    species_gaps,
)
from plantdreamer.exports.yolo import label_lines, link_image, mask_polygons, object_polygon
from plantdreamer.guidance.model_files import model_files_record
from test_card_records import ALL_TRAIN, HOSTILE, SD, dataset_of, local_models

pycocotools = pytest.importorskip("pycocotools")


def read_png(path):
    import imageio.v3 as iio

    return np.asarray(iio.imread(path))


# --- objects of a view ------------------------------------------------------------------


def test_view_objects_make_slivers_ignore_regions_and_never_zero_size_boxes():
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
    assert objects.objects == 2 and objects.ignored == 0
    small = view_objects(semantic, instance, min_area=4)
    assert small.iscrowd.tolist() == [True, False] and small.ignored == 1
    assert small.things().instance_ids.tolist() == [7]
    np.testing.assert_array_equal(small.ignore_mask(), instance == 5)
    with pytest.raises(InputError, match="at least 1 pixel"):
        view_objects(semantic, instance, min_area=0)
    none = view_objects(semantic, instance, min_area=100).things()
    assert none.masks.shape == (0, 8, 10) and none.boxes.shape == (0, 4)


def test_classes_without_instances_are_objects_per_8_connected_piece():
    semantic = np.zeros((10, 12), np.uint8)
    instance = np.zeros((10, 12), np.uint16)
    semantic[0:6, 0:4] = 1  # a leaf, id 0, with two pixels the instance map missed
    instance[0:6, 0:4] = 1
    instance[0, 0:2] = 0
    for k in range(5):  # a diagonal stem: one piece, 8-connected
        semantic[5 + k, 5 + k] = 2
    semantic[0:2, 8:12] = 2  # a second stem piece
    semantic[8:10, 0:4] = 3  # the pot
    objects = view_objects(semantic, instance, min_area=1)
    assert objects.categories.tolist() == [1, 2, 2, 3]
    assert objects.instance_ids.tolist() == [0, -1, -1, -1]
    assert objects.areas.tolist() == [22, 8, 5, 8]  # the leaf's unassigned pixels are no stem
    assert objects.masks[2].sum() == 5 and objects.masks[2][9, 9]


def test_an_instance_without_a_class_is_left_out_and_counted():
    semantic = np.zeros((6, 6), np.uint8)
    instance = np.zeros((6, 6), np.uint16)
    instance[0:3, 0:3] = 1  # an instance whose pixels have no class
    instance[3:6, 3:6] = 2
    semantic[3:6, 3:6] = 1
    objects = view_objects(semantic, instance, min_area=1)
    assert objects.instance_ids.tolist() == [1] and objects.unclassed == 1
    lines = label_lines(objects, {1: 0})
    assert len(lines) == 1 and lines[0].startswith("0 ")


def flood_pieces(mask):
    """8-connected pieces by flood fill, one pixel at a time (the slow reference)."""
    h, w = mask.shape
    labels, n = np.zeros((h, w), np.int32), 0
    for y, x in zip(*np.nonzero(mask), strict=True):
        if labels[y, x]:
            continue
        n += 1
        labels[y, x], stack = n, [(y, x)]
        while stack:
            cy, cx = stack.pop()
            for yy in range(max(cy - 1, 0), min(cy + 2, h)):
                for xx in range(max(cx - 1, 0), min(cx + 2, w)):
                    if mask[yy, xx] and not labels[yy, xx]:
                        labels[yy, xx] = n
                        stack.append((yy, xx))
    return labels, n


def test_pieces_match_a_flood_fill():
    rng = np.random.default_rng(0)
    for _ in range(100):
        shape = rng.integers(1, 25, size=2)
        mask = rng.random(shape) < rng.random()
        got, n = label_pieces(mask)
        want, m = flood_pieces(mask)
        assert n == m
        np.testing.assert_array_equal(got, want)


# --- COCO -------------------------------------------------------------------------------


def test_coco_file_loads_in_pycocotools_and_masks_are_the_instance_pixels(bean):
    from pycocotools import mask as mask_utils
    from pycocotools.coco import COCO

    coco = COCO(str(bean / "coco.json"))
    meta = json.loads((bean / "transforms.json").read_text())
    assert {c["name"] for c in coco.loadCats(coco.getCatIds())} == {"leaf", "stem", "pot", "soil"}
    assert len(coco.getImgIds()) == len(meta["frames"])
    written, crowds, categories = 0, 0, set()
    for image in coco.loadImgs(coco.getImgIds()):
        frame = next(f for f in meta["frames"] if f["file_path"] == image["file_name"])
        instance = read_png(bean / frame["instance_path"]).astype(np.int64)
        semantic = read_png(bean / frame["semantic_path"])
        assert (image["height"], image["width"]) == instance.shape
        anns = coco.loadAnns(coco.getAnnIds(imgIds=image["id"]))
        # Every leaf instance is an annotation, those under the limit as ignore regions.
        ids = np.unique(instance[instance > 0] - 1)
        assert sorted(a["instance_id"] for a in anns if a["instance_id"] >= 0) == ids.tolist()
        covered = np.zeros(instance.shape, int)
        for ann in anns:
            mask = coco.annToMask(ann).astype(bool)
            covered += mask
            if ann["instance_id"] >= 0:
                np.testing.assert_array_equal(mask, instance == ann["instance_id"] + 1)
                assert ann["category_id"] == np.bincount(semantic[mask]).argmax() == 1  # leaves
            else:  # a piece of stem, pot or soil: pixels of its class with no instance
                assert ann["category_id"] in (2, 3, 4)
                assert (semantic[mask] == ann["category_id"]).all() and not instance[mask].any()
            assert ann["iscrowd"] == int(ann["area"] < MIN_INSTANCE_AREA)
            assert ann["area"] == mask.sum() == mask_utils.area(ann["segmentation"])
            w, h = ann["bbox"][2:]
            assert w >= 1 and h >= 1
            written += 1 - ann["iscrowd"]
            crowds += ann["iscrowd"]
            categories.add(ann["category_id"])
        # Every labelled pixel is in exactly one annotation but leaf pixels the instance
        # map has no id for.
        assert covered.max() == 1
        np.testing.assert_array_equal(covered == 1, (instance > 0) | (semantic > 1))
    info = json.loads((bean / "coco.json").read_text())["info"]
    assert written == info["objects"] > 0 and crowds == info["ignore_regions"] > 0
    assert info["min_instance_area"] == MIN_INSTANCE_AREA
    assert categories == set(coco.getCatIds())  # every declared class is annotated


def test_a_smaller_area_limit_writes_more_objects(bean, tmp_path):
    import shutil

    copy = shutil.copytree(bean, tmp_path / "copy")
    before = json.loads((copy / "coco.json").read_text())["info"]
    report = write_plant_exports(copy, min_area=1)
    assert report.ignored == 0
    assert report.objects == before["objects"] + before["ignore_regions"]


def test_every_format_declares_the_same_classes(bean):
    import yaml

    from plantdreamer.data import PlantViews

    names = {1: "leaf", 2: "stem", 3: "pot", 4: "soil"}
    coco = json.loads((bean / "coco.json").read_text())
    assert {c["id"]: c["name"] for c in coco["categories"]} == names
    data = yaml.safe_load((bean / "yolo" / "data.yaml").read_text())
    assert {i + 1: n for i, n in data["names"].items()} == names
    assert read_class_names(bean / "points.ply") == names
    run = json.loads((bean / "run.json").read_text())
    assert {int(k): v for k, v in run["class_names"].items()} == names
    pytest.importorskip("torchvision")
    assert PlantViews(bean).classes == names


def test_a_plant_with_an_instance_without_class_exports_and_says_so(bean, tmp_path):
    import shutil

    import imageio.v3 as iio

    copy = shutil.copytree(bean, tmp_path / "copy")
    semantic = iio.imread(copy / "labels" / "view_000.png")
    instance = iio.imread(copy / "instances" / "view_000.png")
    first = instance[instance > 0].min()
    semantic[instance == first] = 0  # that leaf's pixels lose their class
    iio.imwrite(copy / "labels" / "view_000.png", semantic)
    report = write_plant_exports(copy)
    assert report.unclassed == 1
    coco = json.loads((copy / "coco.json").read_text())
    assert coco["info"]["instances_without_class"] == 1
    assert {a["category_id"] for a in coco["annotations"]} <= {1, 2, 3, 4}
    assert int(first) - 1 not in {
        a["instance_id"] for a in coco["annotations"] if a["image_id"] == 1
    }


# --- YOLO -------------------------------------------------------------------------------


def centres_inside(polygon, shape):
    """Pixels whose centre a polygon (pixel coordinates) contains."""
    from matplotlib.path import Path as Outline

    h, w = shape
    rows, cols = np.mgrid[0:h, 0:w]
    centres = np.c_[cols.reshape(-1) + 0.5, rows.reshape(-1) + 0.5]
    return Outline(polygon).contains_points(centres).reshape(h, w)


def test_polygons_outline_each_piece_of_a_mask():
    mask = np.zeros((12, 12), bool)
    mask[2:6, 1:5] = True
    mask[8:11, 7:11] = True
    rings = mask_polygons(mask)
    assert len(rings) == 2
    xs = sorted((r[:, 0].min(), r[:, 0].max()) for r in rings)
    assert xs == [(1.0, 5.0), (7.0, 11.0)]  # pixel edges: columns 1..4 span x 1..5


def test_pixels_touching_at_a_corner_are_one_piece_not_diamonds():
    mask = np.zeros((30, 30), bool)
    for k in range(24):  # a diagonal leaf edge, 24 pixels touching corner to corner
        mask[3 + k, 2 + k] = True
    rings = mask_polygons(mask)
    assert len(rings) == 1
    np.testing.assert_array_equal(centres_inside(rings[0], mask.shape), mask)


def test_an_object_in_pieces_is_one_polygon_over_all_its_pixels():
    mask = np.zeros((40, 40), bool)
    mask[2:12, 2:14] = True  # a leaf crossed by a stem: three pieces
    mask[15:25, 5:12] = True
    mask[30:37, 30:38] = True
    mask[32, 33] = False  # a hole: YOLO-seg has none, so the polygon covers it
    assert len(mask_polygons(mask)) == 3
    polygon = object_polygon(mask)
    inside = centres_inside(polygon, mask.shape)
    assert (inside & mask).sum() == mask.sum()  # every pixel of every piece
    # The bridges between pieces have no width: nothing else is inside but the hole and
    # pixels whose centre lies on a bridge (where a point-in-polygon test may go either way).
    extra = [(y, x) for y, x in np.argwhere(inside & ~mask) if (y, x) != (32, 33)]
    a, b = polygon, np.roll(polygon, -1, axis=0)
    for y, x in extra:
        c = np.array([x + 0.5, y + 0.5])
        t = np.clip(((c - a) * (b - a)).sum(1) / ((b - a) ** 2).sum(1), 0, 1)
        assert np.min(np.linalg.norm(a + t[:, None] * (b - a) - c, axis=1)) < 1e-9
    objects = view_objects(mask.astype(np.uint8), mask.astype(np.uint16), min_area=1)
    assert len(label_lines(objects, {1: 0})) == 1


def test_linking_an_image_twice_leaves_no_temporary(tmp_path):
    source = tmp_path / "render.png"
    source.write_bytes(b"png")
    target = tmp_path / "yolo" / "images" / "view_000.png"
    for _ in range(2):
        link_image(source, target)
    assert sorted(p.name for p in target.parent.iterdir()) == ["view_000.png"]
    assert target.stat().st_ino == source.stat().st_ino


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
        img = next(i for i in coco["images"] if i["file_name"].endswith(image.name))
        objects = [a for a in coco["annotations"] if a["image_id"] == img["id"]]
        objects = [a for a in objects if not a["iscrowd"]]  # YOLO has no ignore regions
        # One line per object, in COCO's order, of its class.
        assert len(polygons) == len(objects) > 0
        from pycocotools import mask as mask_utils

        for (cls, xy), a in zip(polygons, objects, strict=True):
            assert cls == a["category_id"] - 1
            truth = mask_utils.decode(a["segmentation"]).astype(bool)
            got = centres_inside(xy * [w, h], (h, w))
            # Equal but for holes, which YOLO polygons do not represent, and centres on
            # the bridges that join the pieces.
            assert (got & truth).sum() == truth.sum()
            assert (got & ~truth).sum() <= 0.03 * truth.sum() + 2, a["id"]


# --- splits -----------------------------------------------------------------------------


def test_splits_are_seeded_disjoint_and_by_plant():
    ids = [f"bean-{i:03d}" for i in range(20)]
    a = split_plants(ids, (0.6, 0.2, 0.2), seed=1)
    assert sorted(a["train"] + a["val"] + a["test"]) == ids
    assert split_plants(list(reversed(ids)), (0.6, 0.2, 0.2), seed=1) == a
    assert split_plants(ids, (0.6, 0.2, 0.2), seed=2) != a
    many = split_plants([f"p{i}" for i in range(4000)], (0.6, 0.3, 0.1), seed=0)
    assert [len(many[s]) / 4000 for s in SPLITS] == pytest.approx([0.6, 0.3, 0.1], abs=0.025)
    assert parse_ratios("8,1,1") == pytest.approx((0.8, 0.1, 0.1))
    for bad in ("0.8,0.2", "a,b,c", "0,0,0", "-1,1,1", "1e308,1e308,1"):
        with pytest.raises(InputError, match="--split"):
            parse_ratios(bad)


def test_a_plant_keeps_its_split_when_the_dataset_grows():
    ratios = parse_ratios("0.8,0.1,0.1")
    for seed in range(5):
        small = split_plants([f"bean-s{i:04d}" for i in range(8)], ratios, seed)
        large = split_plants([f"bean-s{i:04d}" for i in range(16)], ratios, seed)
        for split in SPLITS:
            assert set(small[split]) <= set(large[split])


def test_a_zero_share_gets_no_plant():
    for n in (1, 5, 50):
        ids = [f"mint-{i}" for i in range(n)]
        assert split_plants(ids, parse_ratios("0.5,0.5,0"))["test"] == []
        assert split_plants(ids, parse_ratios("0,0,1")) == {
            "train": [],
            "val": [],
            "test": sorted(ids),
        }


def test_an_empty_split_is_an_error_naming_the_counts_unless_allowed():
    ratios = parse_ratios("0.8,0.1,0.1")
    ids = [f"bean-{i}" for i in range(5)]
    seeds = {}
    for seed in range(20):
        splits = split_plants(ids, ratios, seed)
        seeds.setdefault(bool(splits["val"]), seed)
    splits = split_plants(ids, ratios, seeds[False])
    with pytest.raises(InputError, match=r"val .*drew no plant \(\d train, 0 val, \d test of 5"):
        check_splits(splits, ratios)
    (warning,) = check_splits(splits, ratios, allow_empty=True)
    assert "val" in warning
    assert check_splits(split_plants(ids, parse_ratios("1,0,0")), parse_ratios("1,0,0")) == []


def test_a_species_missing_from_a_split_where_expected_is_a_warning():
    species = {f"kale-{i}": "kale" for i in range(10)} | {"mint-0": "mint"}
    splits = {"train": sorted(species), "val": [], "test": []}
    (line,) = species_gaps(splits, species, (0.8, 0.2, 0.0))
    assert line.startswith("no kale plant drew val (10 kale plants")  # mint: 0.2 expected
    assert species_gaps(splits, species, (1.0, 0.0, 0.0)) == []


def test_species_counts_per_split():
    splits = {"train": ["a", "b", "c"], "val": ["d"], "test": []}
    species = {"a": "bean", "b": "mint", "c": "bean", "d": "kale"}
    assert species_counts(splits, species) == {
        "train": {"bean": 2, "mint": 1}, "val": {"kale": 1}, "test": {}
    }  # fmt: skip


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


# --- the dataset's card (its helpers and the model records: test_card_records.py) -------


def test_the_card_reads_what_each_plant_recorded_and_the_hub_reads_the_card(
    bean, tmp_path, monkeypatch
):
    from huggingface_hub import DatasetCard

    base, control, lora = local_models(tmp_path)
    recorded = model_files_record(str(base), str(control), str(lora))
    root = tmp_path / "ds"
    guided = {"guidance": "sds", "base-model": str(base), "controlnet": str(control),
              "lora": str(lora)}  # fmt: skip
    dataset_of(bean, root, {"bean-a": {}, "bean-b": {"config": guided, "models": recorded}})
    # The LoRA retrained in place after the plant was made: the card keeps the plant's.
    (lora / "pytorch_lora_weights.safetensors").write_bytes(b"lora v2")
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1750000000")  # 2025-06-15
    write_dataset_exports(root, ALL_TRAIN)

    card = json.loads((root / "dataset.json").read_text())["card"]
    assert card["date"] == "2025-06-15" and card["guided_plants"] == 1
    models = {m["role"]: m for m in card["models"]}
    lora_file = models["species LoRA"]["files"][0]
    assert lora_file["sha256"] == hashlib.sha256(b"lora v1").hexdigest()
    assert models["base model"]["sha256"] == recorded[0]["sha256"]
    assert "url" not in card
    readme = (root / "README.md").read_text()
    for text in (readme, json.dumps(card)):
        assert str(tmp_path) not in text  # names and hashes, never this machine's paths
    assert recorded[0]["sha256"] in readme and "## Limitations" in readme
    assert "1 of 2 plants" in readme
    # Not Stable Diffusion from the hub: no claim of its weights or licence.
    assert "Stable Diffusion 2.1 weights" not in readme and "RAIL" not in readme
    assert card["licences"]["data"] == "unknown"

    loaded = DatasetCard.load(root / "README.md")
    assert loaded.data.license == "unknown"
    assert loaded.data.task_categories == ["image-segmentation", "object-detection",
                                           "depth-estimation"]  # fmt: skip
    assert card["splits"]["train"]["images"] > 0 and loaded.data.size_categories == ["n<1K"]
    assert loaded.data.pretty_name == "plantdreamer synthetic plants (bean)"
    assert loaded.data.configs == [
        {"config_name": "default",
         "data_files": [{"split": "train", "path": "yolo/images/train/*.png"}]}
    ]  # fmt: skip
    assert loaded.text.lstrip().startswith("# A plantdreamer dataset")
    coco = json.loads((root / "coco" / "train.json").read_text())
    assert coco["info"]["date_created"] == "2025-06-15" and coco["info"]["year"] == 2025
    assert coco["info"]["url"] == "" and all(not lic["url"] for lic in coco["licenses"])
    licence_of = {image["plant_id"]: image["license"] for image in coco["images"]}
    assert licence_of == {"bean-a": 2, "bean-b": 1}

    # A rerun replaces its own card, YAML block and all; a user's README is left alone.
    write_dataset_exports(root, ALL_TRAIN)
    assert (root / "README.md").read_text() == readme
    (root / "README.md").write_text("---\nlicense: mit\n---\n# my notes\n")
    labels = write_dataset_exports(root, ALL_TRAIN)
    assert (root / "README.md").read_text() == "---\nlicense: mit\n---\n# my notes\n"
    assert any("is not a dataset card" in w for w in labels.warnings)


def test_stable_diffusion_from_the_hub_gives_its_licence_and_an_older_plant_no_hash(bean, tmp_path):
    from huggingface_hub import DatasetCard

    sd = [{"role": "base model", "name": SD, "source": "hub", "revision": "5ede9e4",
           "files": [{"path": "unet/x.safetensors", "bytes": 1, "sha256": "a" * 64}],
           "sha256": "b" * 64}]  # fmt: skip
    root = tmp_path / "ds"
    older = {"guidance": "sds", "base-model": "/home/someone/models/sd21",
             "controlnet": "thibaud/controlnet-sd21-depth-diffusers"}  # fmt: skip
    dataset_of(bean, root, {"bean-a": {"config": {"guidance": "sds"}, "models": sd},
                            "bean-b": {"config": older}})  # fmt: skip
    write_dataset_exports(root, ALL_TRAIN)
    card = json.loads((root / "dataset.json").read_text())["card"]
    assert card["licences"]["data"] == "openrail++"
    assert DatasetCard.load(root / "README.md").data.license == "openrail++"
    readme = (root / "README.md").read_text()
    assert "CreativeML Open RAIL++-M" in readme and "Attachment A" in readme
    names = {(m["role"], m["name"], m["sha256"]) for m in card["models"]}
    assert ("base model", SD, "b" * 64) in names
    # The plant recorded no models: named by its settings, a local path by its last part.
    assert ("base model", "sd21", None) in names
    assert ("depth ControlNet", "thibaud/controlnet-sd21-depth-diffusers", None) in names
    assert "/home/someone" not in readme and "/home/someone" not in json.dumps(card)
    coco = json.loads((root / "coco" / "train.json").read_text())
    assert coco["licenses"][0]["name"].startswith("CreativeML Open RAIL++-M")


def test_every_user_given_name_is_escaped_where_the_card_writes_it(bean, tmp_path):
    from huggingface_hub import DatasetCard

    root = tmp_path / "ds"
    hostile_model = [{"role": "base model", "name": "sd|x\n# Models: none", "source": "hub",
                      "revision": "r\nlicense: mit", "files": [], "sha256": None}]  # fmt: skip
    dataset_of(bean, root, {"bean-a": {"config": {"species": HOSTILE}},
                            "bean-b": {"config": {"guidance": "sds"}, "models": hostile_model}})  # fmt: skip
    write_dataset_exports(root, ALL_TRAIN)
    readme = (root / "README.md").read_text()
    body = readme.split("\n---\n", 1)[1]
    # No heading, licence line or HTML that the names brought in.
    headings = [line for line in body.splitlines() if line.startswith("#")]
    assert headings == ["# A plantdreamer dataset", "## Files", "## Classes", "## Plants",
                        "## Distributions", "## Models", "## Limitations", "## Licences", "## Citation"]  # fmt: skip
    assert "<img" not in body and "](https://e.example)" not in body
    assert "&lt;img" in body
    # Each table row keeps its columns: a | in a name is escaped.
    for line in body.splitlines():
        if line.startswith("| "):
            assert len(re.findall(r"(?<!\\)\|", line)) == 5, line
    assert "bean \\| x \\#\\# Licence\\: MIT" in body
    # The YAML block holds the name as one quoted string; the licence is the card's.
    loaded = DatasetCard.load(root / "README.md")
    assert loaded.data.license == "unknown"
    assert "## Licence: MIT" in loaded.data.pretty_name and "\n" not in loaded.data.pretty_name
    # dataset.json keeps the names as they are (JSON quotes them itself).
    card = json.loads((root / "dataset.json").read_text())["card"]
    assert HOSTILE in card["species"]
