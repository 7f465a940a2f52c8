"""Label files read the way their consumers read them: Ultralytics' own YOLO-seg parser
(offline, in a process of its own: tests/ultralytics_reader.py), nerfstudio's camera, depth and point-cloud
conventions (written out from its dataparser and docs: nerfstudio itself is too heavy for
CI) and Open3D called as nerfstudio calls it for splatfacto's initial points."""

from __future__ import annotations

import importlib.util
import json
import os
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from plantdreamer.exports import LabelOptions, write_dataset_exports
from plantdreamer.exports.splits import SPLITS, parse_ratios, split_plants

READER = Path(__file__).with_name("ultralytics_reader.py")


def read_png(path):
    import imageio.v3 as iio

    return np.asarray(iio.imread(path))


# --- Ultralytics ------------------------------------------------------------------------

DATASET_PLANTS = ("bean-a", "bean-b", "bean-c")


@pytest.fixture(scope="module")
def ultralytics_read(bean, tmp_path_factory):
    """A plant's YOLO files and a three-plant dataset's, read by tests/ultralytics_reader.py."""
    if importlib.util.find_spec("ultralytics") is None:
        pytest.skip("ultralytics is not installed (the dev extra has it)")
    root = tmp_path_factory.mktemp("yolo")
    plant_yaml = shutil.copytree(bean / "yolo", root / "plant") / "data.yaml"  # labels.cache
    for plant_id in DATASET_PLANTS:
        shutil.copytree(bean, root / "dataset" / "plants" / plant_id)
    ratios = parse_ratios("1,1,1")
    seed = next(  # a seed that gives each split a plant
        s for s in range(100) if all(split_plants(DATASET_PLANTS, ratios, s).values())
    )
    options = LabelOptions(ratios=ratios, seed=seed)
    splits = write_dataset_exports(root / "dataset", options).splits
    pairs = [(plant_yaml, "train")] + [(root / "dataset/yolo/data.yaml", s) for s in SPLITS]
    out = root / "read.pkl"
    env = {**os.environ, "YOLO_CONFIG_DIR": str(root / "settings"), "YOLO_OFFLINE": "1"}
    args = [sys.executable, str(READER), str(out), *[str(x) for pair in pairs for x in pair]]
    done = subprocess.run(args, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    read = pickle.loads(out.read_bytes())
    assert read["network_calls"] == []
    results = {(Path(y).parent.name, split): r for (y, split), r in read["results"].items()}
    return results, splits


def written_polygons(label_file):
    rows = [line.split() for line in label_file.read_text().splitlines()]
    return [int(r[0]) for r in rows], [np.array(r[1:], np.float64).reshape(-1, 2) for r in rows]


def polygon_pixels(polygons, shape):
    """Pixels whose centre is inside one of the normalised polygons."""
    from matplotlib.path import Path as Outline

    h, w = shape
    rows, cols = np.mgrid[0:h, 0:w]
    centres = np.c_[cols.reshape(-1) + 0.5, rows.reshape(-1) + 0.5]
    inside = np.zeros(h * w, bool)
    for xy in polygons:
        inside |= Outline(np.asarray(xy, np.float64) * [w, h]).contains_points(centres)
    return inside.reshape(h, w)


def grown(mask):
    """The mask and the 8 neighbours of each of its pixels."""
    padded = np.pad(mask, 1)
    h, w = mask.shape
    return np.logical_or.reduce([padded[y : y + h, x : x + w] for y in range(3) for x in range(3)])


@pytest.mark.slow  # Ultralytics' import and a three-plant dataset: ~10 s
def test_ultralytics_reads_a_plants_labels_with_its_classes_and_polygons(bean, ultralytics_read):
    from pycocotools import mask as mask_utils

    plant = ultralytics_read[0][("plant", "train")]
    assert plant["nc"] == 4 and plant["names"] == {0: "leaf", 1: "stem", 2: "pot", 3: "soil"}
    assert set().union(*[im["classes"] for im in plant["images"]]) == {0, 1, 2, 3}
    assert Path(plant["folder"]).name == "images"
    renders = sorted((bean / "renders").glob("*.png"))
    assert sorted(Path(im["file"]).name for im in plant["images"]) == [p.name for p in renders]
    coco = json.loads((bean / "coco.json").read_text())
    for view in plant["images"]:
        name = Path(view["file"]).name
        classes, polygons = written_polygons(bean / "yolo" / "labels" / f"{Path(name).stem}.txt")
        assert view["classes"] == classes
        assert len(view["polygons"]) == len(polygons) > 0
        image = next(im for im in coco["images"] if im["file_name"].endswith(name))
        objects = [
            a for a in coco["annotations"] if a["image_id"] == image["id"] and not a["iscrowd"]
        ]
        # Ultralytics counts the objects COCO has, of the same classes (one line each).
        assert [a["category_id"] - 1 for a in objects] == view["classes"]
        for got, ours in zip(view["polygons"], polygons, strict=True):
            np.testing.assert_allclose(got, ours, atol=1e-6)
        np.testing.assert_array_equal(view["image"], read_png(bean / "renders" / name)[..., :3])
        truth = np.zeros(view["image"].shape[:2], bool)
        for a in objects:
            truth |= mask_utils.decode(a["segmentation"]).astype(bool)
        assert view["masks"].shape == (len(polygons), *truth.shape)
        got = view["masks"].any(0)
        # Ultralytics' masks hold every object pixel and reach at most one pixel beyond
        # the polygons it read: its rasteriser truncates vertices to whole pixels and fills
        # the outline too (a polygon's own pixels are those whose centre it contains), and
        # draws the zero-width bridges between an object's pieces as one-pixel lines.
        assert (got & truth).sum() >= 0.99 * truth.sum()
        beyond = got & ~grown(polygon_pixels(view["polygons"], truth.shape))
        assert beyond.sum() <= 0.02 * truth.sum()


@pytest.mark.slow
def test_ultralytics_reads_each_split_of_a_dataset(bean, ultralytics_read):
    results, splits = ultralytics_read
    n_views = len(list((bean / "renders").glob("*.png")))
    plant_coco = json.loads((bean / "coco.json").read_text())
    objects = {
        Path(im["file_name"]).stem: sum(
            1 for a in plant_coco["annotations"] if a["image_id"] == im["id"] and not a["iscrowd"]
        )
        for im in plant_coco["images"]
    }
    assert sorted(p for ids in splits.values() for p in ids) == list(DATASET_PLANTS)
    for split in SPLITS:
        read = results[("yolo", split)]
        assert read["nc"] == 4 and read["names"][0] == "leaf"
        assert Path(read["folder"]).parts[-2:] == ("images", split)
        plants = [Path(im["file"]).name.split("__")[0] for im in read["images"]]
        assert sorted(plants) == sorted(splits[split] * n_views)
        for view in read["images"]:
            image = Path(view["file"]).stem.split("__")[1]  # <plant id>__<view>
            classes, polygons = written_polygons(bean / "yolo" / "labels" / f"{image}.txt")
            assert view["classes"] == classes and len(view["polygons"]) == len(polygons) > 0
            # YOLO's instance count is COCO's object count, in the split's file too.
            assert len(view["classes"]) == objects[image]
        root = Path(read["folder"]).parents[2]
        split_coco = json.loads((root / "coco" / f"{split}.json").read_text())
        yolo_counts = sorted(
            (Path(v["file"]).stem.replace("__", "/renders/"), len(v["classes"]))
            for v in read["images"]
        )
        coco_counts = sorted(
            (
                im["file_name"].removeprefix("plants/").removesuffix(".png"),
                sum(
                    1
                    for a in split_coco["annotations"]
                    if a["image_id"] == im["id"] and not a["iscrowd"]
                ),
            )
            for im in split_coco["images"]
        )
        assert yolo_counts == coco_counts
        if importlib.util.find_spec("torchvision") is not None:
            from plantdreamer.data import PlantViews

            views = PlantViews(root, split=split)
            by_id = {im["id"]: im["file_name"] for im in split_coco["images"]}
            torch_counts = sorted(
                (
                    by_id[t["image_id"]].removeprefix("plants/").removesuffix(".png"),
                    len(t["labels"]),
                )
                for _, t in views
            )
            assert torch_counts == coco_counts


def readme_yolo_command():
    """The Ultralytics block of docs/datasets.md: its environment and its ``yolo`` command line."""
    import re
    import shlex

    readme = (Path(__file__).parents[1] / "docs" / "datasets.md").read_text()
    (block,) = [b for b in re.findall(r"```bash\n(.*?)```", readme, re.S) if "yolo segment" in b]
    lines = block.replace("\\\n", " ").splitlines()
    env = dict(w.split("=", 1) for w in shlex.split(lines[0].removeprefix("export ")))
    return env, shlex.split(lines[1])


@pytest.mark.slow  # Ultralytics trains 2 epochs on a plant's 3 views: ~30 s
def test_the_readme_ultralytics_command_trains_offline(bean, tmp_path):
    if importlib.util.find_spec("ultralytics") is None:
        pytest.skip("ultralytics is not installed (the dev extra has it)")
    import csv

    env, command = readme_yolo_command()
    assert env == {"YOLO_OFFLINE": "1", "YOLO_CONFIG_DIR": "$PWD/.ultralytics"}
    assert command[:3] == ["yolo", "segment", "train"]
    settings = dict(arg.split("=", 1) for arg in command[3:])
    assert settings.pop("data") == "$PWD/ds/yolo/data.yaml"
    # As written, but for the data (a plant's own data.yaml), the size and the epochs.
    settings.update(imgsz="96", epochs="2", batch="3", workers="0", project=str(tmp_path / "runs"))
    command = [*command[:3], f"data={bean / 'yolo' / 'data.yaml'}"]
    command += [f"{k}={v}" for k, v in settings.items()]
    env = {**os.environ, "YOLO_OFFLINE": "1", "YOLO_CONFIG_DIR": str(tmp_path / "settings")}
    out = tmp_path / "train.json"
    train = Path(__file__).with_name("ultralytics_train.py")
    done = subprocess.run(
        [sys.executable, str(train), str(out), *command],
        env=env, cwd=tmp_path, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, (done.stdout + done.stderr)[-3000:]
    assert json.loads(out.read_text())["network_calls"] == []
    (results,) = (tmp_path / "runs").rglob("results.csv")
    rows = list(csv.DictReader(results.open()))
    assert len(rows) == 2
    for row in rows:
        losses = [float(v) for k, v in row.items() if k.strip().startswith("train/")]
        assert losses and all(np.isfinite(losses)), row


# --- nerfstudio -------------------------------------------------------------------------
# nerfstudio/data/dataparsers/nerfstudio_dataparser.py and docs/quickstart/data_conventions.md:
# transform_matrix is camera-to-world with OpenGL camera axes (+x right, +y up, looking down
# -z), world +z up; the ray of pixel (row, col) goes through (col + 0.5, row + 0.5), along
# ((x - cx) / fx, -(y - cy) / fy, -1) in camera axes (cameras.py); depth PNGs hold z along
# the optical axis (losses.py multiplies them by the ray direction's norm) in units of the
# dataparser's depth_unit_scale_factor, 1e-3 unless set on its command line; the
# ply_file_path points are read by Open3D and moved by the same transform as the poses,
# after applied_transform (3x4) when the file has one.

NERFSTUDIO_DEPTH_UNIT = 1e-3


def nerfstudio_points(meta, folder):
    """The ply_file_path points, labels and instances in the frame of the poses."""
    from plyfile import PlyData

    v = PlyData.read(str(folder / meta["ply_file_path"]))["vertex"]
    xyz = np.c_[v["x"], v["y"], v["z"]].astype(np.float64)
    applied = np.asarray(meta.get("applied_transform", np.eye(4)[:3]), np.float64)
    xyz = (xyz @ applied[:, :3].T + applied[:, 3]) * float(meta.get("applied_scale", 1.0))
    return xyz, np.asarray(v["label"]), np.asarray(v["instance"])


def nerfstudio_pixels(meta, c2w, xyz):
    """Row, column and z-depth of world points seen by a nerfstudio camera (NaN behind it)."""
    cam = (xyz - c2w[:3, 3]) @ c2w[:3, :3]
    depth = np.where(cam[:, 2] < 0, -cam[:, 2], np.nan)
    col = meta["cx"] + meta["fl_x"] * cam[:, 0] / depth
    row = meta["cy"] - meta["fl_y"] * cam[:, 1] / depth
    return np.floor(row), np.floor(col), depth


def on_plant_fraction(meta, folder, change):
    """The share of points that land on mask pixels, each pose passed through ``change``."""
    xyz, _, _ = nerfstudio_points(meta, folder)
    hits = []
    for frame in meta["frames"]:
        mask = read_png(folder / frame["mask_path"]) > 0  # nerfstudio: non-zero = used
        pose = np.array(frame["transform_matrix"], np.float64)
        row, col, _ = nerfstudio_pixels(meta, change(pose), xyz)
        inside = (row >= 0) & (row < meta["h"]) & (col >= 0) & (col < meta["w"])
        hit = np.zeros(len(xyz), bool)
        hit[inside] = mask[row[inside].astype(int), col[inside].astype(int)]
        hits.append(hit)
    return np.mean(hits)


def test_nerfstudio_cameras_put_the_points_on_their_plant_class_and_leaf(bean):
    meta = json.loads((bean / "transforms.json").read_text())
    assert meta["camera_model"] in ("OPENCV", "PINHOLE") and not any(
        k in meta for k in ("k1", "k2", "k3", "k4", "p1", "p2")
    )
    xyz, label, instance = nerfstudio_points(meta, bean)
    for frame in meta["frames"]:
        c2w = np.array(frame["transform_matrix"], np.float64)
        image = read_png(bean / frame["file_path"])
        assert image.shape[:2] == (meta["h"], meta["w"])
        row, col, z = nerfstudio_pixels(meta, c2w, xyz)
        inside = (row >= 0) & (row < meta["h"]) & (col >= 0) & (col < meta["w"])
        assert inside.all()  # the whole plant is in every view
        row, col = row.astype(int), col.astype(int)
        assert (read_png(bean / frame["mask_path"])[row, col] > 0).mean() > 0.99
        # Points on the surface (z-depth as the depth PNG has it) land on their own class
        # and leaf; a point behind a leaf lands on that leaf, so those are left out.
        depth = read_png(bean / frame["depth_file_path"]) * NERFSTUDIO_DEPTH_UNIT
        seen = np.abs(depth[row, col] - z) < 0.005
        assert seen.sum() > 100
        semantic = read_png(bean / frame["semantic_path"])[row[seen], col[seen]]
        assert (semantic == label[seen]).mean() > 0.97
        ids = read_png(bean / frame["instance_path"]).astype(np.int64)[row[seen], col[seen]]
        assert (ids == instance[seen] + 1).mean() > 0.95
    # The same measure with a slip of convention falls far short, so the test would catch one.
    assert on_plant_fraction(meta, bean, lambda pose: pose) > 0.99
    slips = {
        "OpenCV axes": lambda pose: pose @ np.diag([1.0, -1.0, -1.0, 1.0]),
        "image y down": lambda pose: pose @ np.diag([1.0, -1.0, 1.0, 1.0]),
        "world-to-camera": np.linalg.inv,
    }
    for name, slip in slips.items():
        assert on_plant_fraction(meta, bean, slip) < 0.7, name


def test_nerfstudio_world_is_z_up_and_depth_is_z_in_its_unit(bean):
    meta = json.loads((bean / "transforms.json").read_text())
    # nerfstudio reads the depth unit from its own option, not the file: the file's value
    # must be the option's default for the depth to load in metres as it is.
    assert meta["depth_unit_scale_factor"] == NERFSTUDIO_DEPTH_UNIT
    xyz, label, _ = nerfstudio_points(meta, bean)
    assert xyz[label == 3, 2].mean() < xyz[label == 1, 2].mean()  # the pot below the leaves
    for frame in meta["frames"]:
        c2w = np.array(frame["transform_matrix"], np.float64)
        assert c2w[2, 1] > 0  # the camera's up points up the world's +z
        depth = read_png(bean / frame["depth_file_path"]) * NERFSTUDIO_DEPTH_UNIT
        row, col = np.nonzero(depth > 0)
        rays = np.c_[
            (col + 0.5 - meta["cx"]) / meta["fl_x"],
            -(row + 0.5 - meta["cy"]) / meta["fl_y"],
            -np.ones(len(row)),
        ]
        gaps = {}
        for reading, scale in (("z", 1.0), ("ray length", 1 / np.linalg.norm(rays, axis=1))):
            world = (depth[row, col] * scale)[:, None] * rays @ c2w[:3, :3].T + c2w[:3, 3]
            nearest = np.sqrt(((world[:, None] - xyz[None]) ** 2).sum(-1).min(1))
            gaps[reading] = np.median(nearest)
        # Gaussians 4 mm across, some 3000 of them: z lands ~6 mm from a centre, reading
        # the same PNG as ray lengths lands more than twice as far.
        assert gaps["z"] < 0.008 and gaps["ray length"] > 1.5 * gaps["z"], gaps


def test_nerfstudio_reads_the_initial_points_and_colours_through_open3d(bean):
    o3d = pytest.importorskip("open3d")
    from plyfile import PlyData

    from plantdreamer.io import read_splat_ply

    meta = json.loads((bean / "transforms.json").read_text())
    assert "applied_transform" not in meta  # the points are in the poses' frame as they are
    # nerfstudio's _load_3D_points: Open3D's legacy reader, colours * 255 as uint8.
    cloud = o3d.io.read_point_cloud(str(bean / meta["ply_file_path"]))
    points = np.asarray(cloud.points, dtype=np.float32)
    colours = (np.asarray(cloud.colors) * 255).astype(np.uint8)
    np.testing.assert_array_equal(points, read_splat_ply(bean / "plant.ply").means)
    v = PlyData.read(str(bean / meta["ply_file_path"]))["vertex"]
    np.testing.assert_array_equal(colours, np.c_[v["red"], v["green"], v["blue"]])
    assert colours.std() > 5  # the plant's colours, not one grey
