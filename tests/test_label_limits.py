"""What the per-view masks can hold: label limits checked before the first step, ids outside
the masks' range mapped (and the map recorded), negative class ids, and depth that never
saturates whatever the input's units."""

import json

import imageio.v3 as iio
import numpy as np
import pytest
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.cloud import PointCloud
from plantdreamer.errors import InputError
from plantdreamer.io import write_ply
from plantdreamer.labels import check_mask_limits, find_label_fields

RUN = ["--guidance", "none", "--points", "2000", "--eval-views", "2", "--resolution", "48",
       "--turntable", "none"]  # fmt: skip


def blobs(tmp_path, classes, instances=None, scale=1.0):
    """One blob of 300 points per entry of ``classes`` (and ``instances``), side by side."""
    rng = np.random.default_rng(3)
    k = len(classes)
    centres = np.stack([np.arange(k) * 1.0, np.zeros(k), np.zeros(k)], axis=1)
    which = np.repeat(np.arange(k), 300)
    pts = (centres[which] + rng.normal(scale=0.2, size=(300 * k, 3))) * scale
    attributes = {"class": np.asarray(classes, np.int32)[which]}
    if instances is not None:
        attributes["instance"] = np.asarray(instances, np.int32)[which]
    cloud = PointCloud(
        pts.astype(np.float32), colors=rng.random((300 * k, 3), dtype=np.float32),
        attributes=attributes,
    )  # fmt: skip
    write_ply(tmp_path / "scan.ply", cloud)
    return tmp_path / "scan.ply"


def generate(scan, out, *extra):
    return CliRunner().invoke(
        main, ["generate", "--pointcloud", str(scan), *RUN, *extra, "--out", str(out)]
    )


def test_negative_class_ids_are_classes_with_pixel_values(tmp_path):
    scan = blobs(tmp_path, [-3, -4, -5, -6])
    result = generate(scan, tmp_path / "out", "--steps", "0")
    assert result.exit_code == 0, result.output
    meta = json.loads((tmp_path / "out" / "transforms.json").read_text())
    assert [(c["class"], c["value"]) for c in meta["semantic_classes"]] == [
        (-6, 1), (-5, 2), (-4, 3), (-3, 4)
    ]  # fmt: skip
    masks = [iio.imread(tmp_path / "out" / "labels" / f"view_00{i}.png") for i in (0, 1)]
    assert all((m > 0).mean() > 0.02 for m in masks)
    assert set(np.unique(np.concatenate([m.ravel() for m in masks]))) <= {0, 1, 2, 3, 4}


def test_too_many_classes_fail_before_the_first_step(tmp_path):
    scan = blobs(tmp_path, list(range(256)))
    result = generate(scan, tmp_path / "out", "--steps", "30", "--points", "80000")
    assert result.exit_code == 1
    assert "256 distinct classes do not fit an 8-bit class mask" in result.output
    assert "Traceback" not in result.output
    left = {p.name for p in (tmp_path / "out").iterdir()} if (tmp_path / "out").exists() else set()
    assert not left & {"plant.ply", "checkpoint.pt", "log.csv"}, left


def test_instance_ids_beyond_16_bits_are_mapped_and_the_map_recorded(tmp_path):
    ids = [70000 + 1000 * i for i in range(40)]
    scan = blobs(tmp_path, [1] * 40, ids)
    result = generate(scan, tmp_path / "out", "--steps", "0", "--points", "12000")
    assert result.exit_code == 0, result.output
    meta = json.loads((tmp_path / "out" / "transforms.json").read_text())
    mapping = {m["value"]: m["instance"] for m in meta["instance_ids"]}
    assert sorted(mapping) == list(range(1, 41)) and sorted(mapping.values()) == ids
    seen = iio.imread(tmp_path / "out" / "instances" / "view_000.png")
    assert seen.max() <= 40 and len(np.unique(seen)) > 5


def test_mask_limits_count_distinct_ids_and_skip_none():
    labels = np.zeros((70000, 2), np.int32)
    labels[:, 1] = np.arange(70000)
    with pytest.raises(InputError, match="70000 distinct instances"):
        check_mask_limits(labels)
    labels[:, 1] = np.arange(70000) % 65535 - 1  # 65534 ids and -1 (none)
    check_mask_limits(labels)


def test_depth_of_a_scan_in_millimetres_does_not_saturate(tmp_path):
    scan = blobs(tmp_path, [1, 2], scale=1000.0)  # a 2 m wide plant, in millimetres
    result = generate(scan, tmp_path / "out", "--steps", "0")
    assert result.exit_code == 0, result.output
    meta = json.loads((tmp_path / "out" / "transforms.json").read_text())
    factor = meta["depth_unit_scale_factor"]
    assert factor in (0.01, 0.1, 1.0)
    depth = iio.imread(tmp_path / "out" / "depth" / "view_000.png")
    plant = depth[depth > 0]
    assert plant.size and not (plant == 65535).any()
    # Back in input units: the camera is 4 scene units from the centre, the scene is 4
    # units for the scan's longest side (about 1.6 m here).
    run = json.loads((tmp_path / "out" / "run.json").read_text())
    distance = 4.0 / run["transform"]["scale"]
    assert 0.5 * distance < np.median(plant) * factor < 1.5 * distance


def test_a_label_field_that_is_a_coordinate_is_named_as_such():
    with pytest.raises(InputError, match="'x' is the points' position, normal or colour"):
        find_label_fields({"class": np.zeros(3)}, label_field="x")
