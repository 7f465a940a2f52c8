"""A dataset folder's label files: splits by plant, COCO and YOLO per split, the torch Dataset
of a split, and the gallery (``plantdreamer labels`` and ``gallery``, no Ray needed)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from labelled_plant import make_plant
from plantdreamer.cli import main

pytest.importorskip("pycocotools")
PLANTS = {"bean-a": dict(species="bean", seed=1), "bean-b": dict(species="bean", seed=2),
          "mint-a": dict(species="mint", seed=1)}  # fmt: skip


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds")
    for plant_id, settings in PLANTS.items():
        make_plant(root / "plants" / plant_id, eval_views=2, resolution=64, **settings)
    return root


def cli(*args):
    return CliRunner().invoke(main, [*map(str, args)])


def test_labels_split_by_plant_into_coco_and_yolo(dataset):
    from pycocotools.coco import COCO

    result = cli("labels", dataset, "--split", "1,1,1", "--split-seed", "4")
    assert result.exit_code == 0, result.output
    assert "gallery" in result.output
    splits = json.loads((dataset / "splits.json").read_text())
    assert sorted(splits["train"] + splits["val"] + splits["test"]) == sorted(PLANTS)
    assert [len(splits[s]) for s in ("train", "val", "test")] == [1, 1, 1]
    for split in ("train", "val", "test"):
        coco = COCO(str(dataset / "coco" / f"{split}.json"))
        images = coco.loadImgs(coco.getImgIds())
        assert len(images) == 2  # the views of its one plant
        for image in images:
            assert image["file_name"].startswith(f"plants/{splits[split][0]}/renders/")
            assert (dataset / image["file_name"]).is_file()
        ids = [a["id"] for a in coco.loadAnns(coco.getAnnIds())]
        assert len(ids) == len(set(ids))
        yolo_images = sorted((dataset / "yolo" / "images" / split).glob("*.png"))
        assert [p.name.split("__")[0] for p in yolo_images] == [splits[split][0]] * 2
        for image in yolo_images:
            assert (dataset / "yolo" / "labels" / split / f"{image.stem}.txt").is_file()
    data_yaml = (dataset / "yolo" / "data.yaml").read_text()
    assert 'train: "images/train"' in data_yaml and "nc: 4" in data_yaml


def test_a_split_is_a_torch_dataset_of_its_plants(dataset):
    pytest.importorskip("torchvision")
    from plantdreamer.data import PlantViews

    assert cli("labels", dataset, "--split", "2,1,0").exit_code == 0
    splits = json.loads((dataset / "splits.json").read_text())
    train = PlantViews(dataset, split="train")
    assert len(train) == 2 * len(splits["train"]) == 4
    assert {train.describe(i).split("/plants/")[1].split("/")[0] for i in range(4)} == set(
        splits["train"]
    )
    assert len(PlantViews(dataset, split="test")) == 0
    assert len(PlantViews(dataset)) == 6


def test_another_area_limit_remakes_each_plants_files(dataset):
    assert cli("labels", dataset, "--min-instance-area", "1").exit_code == 0
    for plant_id in PLANTS:
        info = json.loads((dataset / "plants" / plant_id / "coco.json").read_text())["info"]
        assert info["min_instance_area"] == 1 and info["objects_left_out"] == 0
    coco = json.loads((dataset / "coco" / "train.json").read_text())
    assert coco["info"]["min_instance_area"] == 1


def test_labels_of_one_plant_folder(dataset):
    plant = dataset / "plants" / "bean-a"
    result = cli("labels", plant, "--min-instance-area", "1")
    assert result.exit_code == 0, result.output
    assert "objects in 2 images (0 under 1 pixels left out)" in result.output
    assert json.loads((plant / "coco.json").read_text())["info"]["min_instance_area"] == 1


def test_gallery_shows_every_plant(dataset, tmp_path):
    import imageio.v3 as iio

    result = cli("gallery", dataset, "--out", tmp_path / "g.png")
    assert result.exit_code == 0, result.output
    image = iio.imread(tmp_path / "g.png")
    # Two plants a row (ceil(sqrt(3))), two rows; each pair is two 1.8-inch panels at 100 dpi.
    assert image.shape[1] == 4 * 180 and image.shape[0] == 2 * (180 + 25)
    assert np.asarray(image)[..., :3].std() > 10  # pictures, not a blank page
    # The same folder gives the same bytes.
    cli("gallery", dataset, "--out", tmp_path / "again.png")
    assert (tmp_path / "again.png").read_bytes() == (tmp_path / "g.png").read_bytes()
    plant = dataset / "plants" / "mint-a"
    assert cli("gallery", plant, "--out", tmp_path / "one.png").exit_code == 0


@pytest.mark.parametrize(
    ("args", "message"),
    [(["--split", "1,1"], "--split"), (["--min-instance-area", "0"], "min-instance-area")],
)
def test_bad_label_options_are_one_error_line(dataset, args, message):
    result = cli("labels", dataset, *args)
    assert result.exit_code != 0 and message in result.output
    assert "Traceback" not in result.output


def test_an_empty_folder_is_one_error_line(tmp_path):
    for command in ("labels", "gallery"):
        result = cli(command, tmp_path)
        assert result.exit_code == 1
        assert result.output.strip().startswith("error:") and "Traceback" not in result.output
