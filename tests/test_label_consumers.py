"""Label files read the way their consumers read them: Ultralytics' own YOLO-seg parser
(offline, its settings in a temporary folder), nerfstudio's camera, depth and point-cloud
conventions (written out from its dataparser and docs: nerfstudio itself is too heavy for
CI) and Open3D called as nerfstudio calls it for splatfacto's initial points."""

from __future__ import annotations

import importlib.util
import json
import shutil
import socket
from pathlib import Path

import numpy as np
import pytest

from plantdreamer.exports import LabelOptions, write_dataset_exports
from plantdreamer.exports.splits import SPLITS, parse_ratios


def read_png(path):
    import imageio.v3 as iio

    return np.asarray(iio.imread(path))


# --- Ultralytics ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ultralytics_offline(tmp_path_factory):
    """Ultralytics imported with its settings in a temporary folder, its online check off
    and the network closed. Yields the list of network calls it tried (tests want none)."""
    if importlib.util.find_spec("ultralytics") is None:
        pytest.skip("ultralytics is not installed (the dev extra has it)")
    config = tmp_path_factory.mktemp("ultralytics")
    attempts: list[tuple] = []

    def no_network(*args, **kwargs):
        attempts.append(args)
        raise OSError("the network is closed in the tests")

    with pytest.MonkeyPatch.context() as mp:
        # Both are read when ultralytics is imported, so they are set before.
        mp.setenv("YOLO_CONFIG_DIR", str(config))
        mp.setenv("YOLO_OFFLINE", "1")
        mp.setattr(socket, "getaddrinfo", no_network)
        mp.setattr(socket, "create_connection", no_network)
        mp.setattr(socket.socket, "connect", no_network)
        from matplotlib import font_manager
        from ultralytics.utils import USER_CONFIG_DIR

        assert Path(USER_CONFIG_DIR).is_relative_to(config), USER_CONFIG_DIR
        # check_det_dataset looks for its plotting font here before it downloads one.
        shutil.copyfile(font_manager.findfont("DejaVu Sans"), USER_CONFIG_DIR / "Arial.ttf")
        yield attempts


def yolo_views(data, split):
    from ultralytics.cfg import get_cfg
    from ultralytics.data import YOLODataset

    # Masks at image resolution (mask_ratio 1), one per polygon (no overlap encoding).
    hyp = get_cfg(overrides={"mask_ratio": 1, "overlap_mask": False})
    size = read_png(next(Path(data[split]).glob("*.png"))).shape[0]
    return YOLODataset(
        img_path=data[split], imgsz=size, augment=False, hyp=hyp, data=data, task="segment"
    )


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
    """The mask and its 8 neighbours of each pixel."""
    padded = np.pad(mask, 1)
    h, w = mask.shape
    return np.logical_or.reduce([padded[y : y + h, x : x + w] for y in range(3) for x in range(3)])


def test_ultralytics_reads_a_plants_labels_with_its_classes_and_polygons(
    bean, tmp_path, ultralytics_offline
):
    from ultralytics.data.utils import check_det_dataset

    yolo_dir = shutil.copytree(bean / "yolo", tmp_path / "yolo")  # it writes labels.cache
    data = check_det_dataset(str(yolo_dir / "data.yaml"), autodownload=False)
    assert data["nc"] == 4 and data["names"] == {0: "leaf", 1: "stem", 2: "pot", 3: "soil"}
    assert data["train"] == data["val"] == str((yolo_dir / "images").resolve())
    views = yolo_views(data, "train")
    renders = sorted((bean / "renders").glob("*.png"))
    assert sorted(Path(lab["im_file"]).name for lab in views.labels) == [p.name for p in renders]
    coco = json.loads((bean / "coco.json").read_text())
    for i, label in enumerate(views.labels):
        name = Path(label["im_file"]).name
        classes, polygons = written_polygons(yolo_dir / "labels" / f"{Path(name).stem}.txt")
        assert label["cls"].reshape(-1).tolist() == classes and set(classes) == {0}  # leaves
        assert len(label["segments"]) == len(polygons) > 0
        for got, ours in zip(label["segments"], polygons, strict=True):
            np.testing.assert_allclose(got, ours, atol=1e-6)
        item = views[i]
        np.testing.assert_array_equal(
            item["img"].numpy().transpose(1, 2, 0), read_png(bean / "renders" / name)[..., :3]
        )
        image = next(im for im in coco["images"] if im["file_name"].endswith(name))
        instance = read_png(bean / "instances" / name).astype(np.int64)
        truth = np.zeros(instance.shape, bool)
        for a in coco["annotations"]:
            if a["image_id"] == image["id"]:
                truth |= instance == a["instance_id"] + 1
        masks = item["masks"].numpy().astype(bool)
        assert masks.shape == (len(polygons), *truth.shape)
        got = masks.any(0)
        # Ultralytics' masks hold every object pixel and reach at most one pixel beyond
        # the polygons it read: its rasteriser truncates vertices to whole pixels and fills
        # the outline too (a polygon's own pixels are those whose centre it contains).
        assert (got & truth).sum() >= 0.99 * truth.sum()
        assert not (got & ~grown(polygon_pixels(label["segments"], truth.shape))).any()
    assert not ultralytics_offline


def test_ultralytics_reads_each_split_of_a_dataset(bean, tmp_path, ultralytics_offline):
    from ultralytics.data.utils import check_det_dataset

    for plant_id in ("bean-a", "bean-b", "bean-c"):
        shutil.copytree(bean, tmp_path / "plants" / plant_id)
    labels = write_dataset_exports(tmp_path, LabelOptions(ratios=parse_ratios("1,1,1"), seed=0))
    data = check_det_dataset(str(tmp_path / "yolo" / "data.yaml"), autodownload=False)
    assert data["nc"] == 4 and data["names"][0] == "leaf"
    n_views = len(list((bean / "renders").glob("*.png")))
    for split in SPLITS:
        views = yolo_views(data, split)
        plants = [Path(lab["im_file"]).name.split("__")[0] for lab in views.labels]
        assert sorted(plants) == sorted(labels.splits[split] * n_views)
        for label in views.labels:
            label_file = tmp_path / "yolo" / "labels" / split / f"{Path(label['im_file']).stem}.txt"
            assert len(label["segments"]) == len(written_polygons(label_file)[1]) > 0
    assert not ultralytics_offline


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
