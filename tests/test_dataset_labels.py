"""A dataset folder's label files: splits by plant, COCO and YOLO per split, the torch Dataset
of a split, and the gallery (``plantdreamer labels`` and ``gallery``, no Ray needed)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from labelled_plant import make_plant
from plantdreamer.cli import main
from plantdreamer.errors import InputError
from plantdreamer.exports.splits import SPLITS, parse_ratios, split_plants

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


def seed_with_one_plant_a_split():
    """A --split-seed that gives each split one plant at 1,1,1 (by the splits' own rule)."""
    ratios = parse_ratios("1,1,1")
    return next(
        seed
        for seed in range(100)
        if all(len(ids) == 1 for ids in split_plants(PLANTS, ratios, seed).values())
    )


def test_labels_split_by_plant_into_coco_and_yolo(dataset):
    from pycocotools.coco import COCO

    seed = seed_with_one_plant_a_split()
    result = cli("labels", dataset, "--split", "1,1,1", "--split-seed", seed)
    assert result.exit_code == 0, result.output
    assert "gallery" in result.output
    splits = json.loads((dataset / "splits.json").read_text())
    assert sorted(splits["train"] + splits["val"] + splits["test"]) == sorted(PLANTS)
    assert [len(splits[s]) for s in ("train", "val", "test")] == [1, 1, 1]
    # The summary says per split how many plants of each species.
    species = {split: PLANTS[splits[split][0]]["species"] for split in SPLITS}
    assert splits["species"] == {split: {species[split]: 1} for split in SPLITS}
    assert f"1 train (1 {species['train']})" in result.output
    image_ids, annotation_ids = set(), set()
    for split in ("train", "val", "test"):
        coco = COCO(str(dataset / "coco" / f"{split}.json"))
        images = coco.loadImgs(coco.getImgIds())
        assert len(images) == 2  # the views of its one plant
        for image in images:
            assert image["file_name"].startswith(f"plants/{splits[split][0]}/renders/")
            assert (dataset / image["file_name"]).is_file()
        ids = [a["id"] for a in coco.loadAnns(coco.getAnnIds())]
        assert len(ids) == len(set(ids))
        # Ids unique across the splits' files: they merge without renumbering.
        assert not image_ids & set(coco.getImgIds()) and not annotation_ids & set(ids)
        image_ids |= set(coco.getImgIds())
        annotation_ids |= set(ids)
        yolo_images = sorted((dataset / "yolo" / "images" / split).glob("*.png"))
        assert [p.name.split("__")[0] for p in yolo_images] == [splits[split][0]] * 2
        for image in yolo_images:
            label = dataset / "yolo" / "labels" / split / f"{image.stem}.txt"
            coco_image = next(
                i for i in images if i["file_name"].endswith(image.name.split("__")[1])
            )
            objects = coco.getAnnIds(imgIds=coco_image["id"], iscrowd=False)
            assert len(label.read_text().splitlines()) == len(objects)
    assert image_ids == set(range(1, 7))
    data_yaml = (dataset / "yolo" / "data.yaml").read_text()
    assert 'train: "images/train"' in data_yaml and "nc: 4" in data_yaml


def test_perfect_predictions_from_the_torch_dataset_score_ap_1_against_the_coco_files(dataset):
    pytest.importorskip("torchvision")
    from pycocotools import mask as mask_utils
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    from plantdreamer.data import PlantViews

    seed = seed_with_one_plant_a_split()
    assert cli("labels", dataset, "--split", "1,1,1", "--split-seed", seed).exit_code == 0
    annotated = set()
    for split in SPLITS:
        truth = COCO(str(dataset / "coco" / f"{split}.json"))
        predictions = []
        for _, target in PlantViews(dataset, split=split):
            masks = target["masks"].numpy().astype(np.uint8)
            rles = mask_utils.encode(np.asfortranarray(masks.transpose(1, 2, 0)))
            for k, rle in enumerate(rles):
                x0, y0, x1, y1 = target["boxes"][k].tolist()
                predictions.append(
                    {
                        "image_id": target["image_id"],
                        "category_id": int(target["labels"][k]),
                        "segmentation": {"size": rle["size"], "counts": rle["counts"].decode()},
                        "bbox": [x0, y0, x1 - x0, y1 - y0],
                        "score": 1.0,
                    }
                )
        assert len(predictions) == len(truth.getAnnIds(iscrowd=False)) > 0
        for kind in ("segm", "bbox"):
            scores = COCOeval(truth, truth.loadRes(predictions), kind)
            scores.params.maxDets = [1, 10, 1000]  # more than any view's objects
            scores.evaluate()
            scores.accumulate()
            # AP over IoU 0.5:0.95, every area, the largest maxDets (summarize's stats[0]
            # is read at maxDets 100 whatever the parameters say).
            precision = scores.eval["precision"][:, :, :, 0, -1]
            assert precision[precision > -1].mean() == pytest.approx(1.0), (split, kind)
        annotated |= {a["category_id"] for a in truth.loadAnns(truth.getAnnIds())}
    # Every class the files declare is annotated in the dataset.
    assert annotated == set(truth.getCatIds()) == {1, 2, 3, 4}


def test_a_split_that_draws_no_plant_is_an_error_unless_allowed(dataset):
    ratios = parse_ratios("0.8,0.1,0.1")
    seed = next(s for s in range(100) if not split_plants(PLANTS, ratios, s)["val"])
    result = cli("labels", dataset, "--split-seed", seed)
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert result.output.startswith("error: split val") and "of 3 plants" in result.output
    allowed = cli("labels", dataset, "--split-seed", seed, "--allow-empty-split")
    assert allowed.exit_code == 0, allowed.output
    assert "warning: split val" in allowed.output


def test_exact_splits_give_the_shares_counts_and_the_card_says_which_mode(dataset):
    """At 2,1,0 the three plants (two beans, a mint) are 2 train, 1 val, a bean in each,
    whatever the seed; the draw's counts vary by seed. The card says which rule it was."""
    ratios = parse_ratios("2,1,0")
    drawn = {len(split_plants(PLANTS, ratios, s)["train"]) for s in range(20)}
    assert drawn != {2}  # the draw: expected shares only
    seed = next(s for s in range(20) if len(split_plants(PLANTS, ratios, s)["train"]) != 2)
    result = cli("labels", dataset, "--split", "2,1,0", "--split-seed", seed,
                 "--split-mode", "exact")  # fmt: skip
    assert result.exit_code == 0, result.output
    splits = json.loads((dataset / "splits.json").read_text())
    assert splits["mode"] == "exact" and [len(splits[s]) for s in SPLITS] == [2, 1, 0]
    assert splits["species"]["train"] == {"bean": 1, "mint": 1}
    card = (dataset / "README.md").read_text()
    assert "train 0.6667 / val 0.3333 / test 0 exactly (`--split-mode exact`)" in card
    assert cli("labels", dataset, "--split", "2,1,0", "--split-seed", seed,
               "--allow-empty-split").exit_code == 0  # fmt: skip
    assert json.loads((dataset / "splits.json").read_text())["mode"] == "draw"
    assert "at expected shares of train 0.6667" in (dataset / "README.md").read_text()
    wrong = cli("labels", dataset, "--split-mode", "quota")
    assert wrong.exit_code == 2 and "'quota' is not one of 'draw', 'exact'" in wrong.output


def test_a_split_is_a_torch_dataset_of_its_plants(dataset):
    pytest.importorskip("torchvision")
    from plantdreamer.data import PlantViews

    ratios = parse_ratios("2,1,0")
    seed = next(s for s in range(100) if len(split_plants(PLANTS, ratios, s)["train"]) == 2)
    assert cli("labels", dataset, "--split", "2,1,0", "--split-seed", seed).exit_code == 0
    splits = json.loads((dataset / "splits.json").read_text())
    train = PlantViews(dataset, split="train")
    assert len(train) == 2 * len(splits["train"]) == 4
    assert {train.describe(i).split("/plants/")[1].split("/")[0] for i in range(4)} == set(
        splits["train"]
    )
    assert len(PlantViews(dataset, split="test")) == 0
    assert len(PlantViews(dataset)) == 6


def test_each_splits_counts_are_its_coco_images_and_the_torch_targets(dataset):
    pytest.importorskip("torchvision")
    import csv

    from plantdreamer.data import PlantViews

    figures = ("leaf_count", "plant_area_px", "plant_height_px", "plant_width_px")
    counted: dict[int, dict[str, int]] = {}
    for min_area in (16, 1):
        args = ("--split", "2,1,0", "--allow-empty-split", "--min-instance-area", min_area)
        assert cli("labels", dataset, *args).exit_code == 0
        counted[min_area] = {}
        for split in SPLITS:
            coco = json.loads((dataset / "coco" / f"{split}.json").read_text())
            with open(dataset / "counts" / f"{split}.csv", newline="") as f:
                rows = list(csv.DictReader(f))
            assert [r["file_name"] for r in rows] == [i["file_name"] for i in coco["images"]]
            views = PlantViews(dataset, split=split)
            for row, image, (_, target) in zip(rows, coco["images"], views, strict=True):
                assert row["plant_id"] == image["plant_id"]
                for key in figures:
                    assert int(row[key]) == image[key] == target[key]
                leaves = [a for a in coco["annotations"] if a["image_id"] == image["id"]
                          and a["category_id"] == 1 and not a["iscrowd"]]  # fmt: skip
                assert image["leaf_count"] == len(leaves)
                counted[min_area][image["file_name"]] = image["leaf_count"]
                traits = json.loads(
                    (dataset / "plants" / row["plant_id"] / "traits.json").read_text()
                )
                assert target["traits"]["leaf_area"] == traits["plant"]["leaf_area"]
            # One row per plant of the split, and per leaf, from its traits.json.
            with open(dataset / "traits" / f"{split}.csv", newline="") as f:
                plants = list(csv.DictReader(f))
            with open(dataset / "traits" / f"{split}_leaves.csv", newline="") as f:
                leaves = list(csv.DictReader(f))
            assert sorted(p["plant_id"] for p in plants) == sorted({r["plant_id"] for r in rows})
            for plant in plants:
                traits = json.loads(
                    (dataset / "plants" / plant["plant_id"] / "traits.json").read_text()
                )
                assert int(plant["leaf_count"]) == traits["plant"]["leaf_count"]
                assert float(plant["height"]) == traits["plant"]["height"]
                mine = [leaf for leaf in leaves if leaf["plant_id"] == plant["plant_id"]]
                assert [float(leaf["area"]) for leaf in mine] == [
                    leaf["area"] for leaf in traits["leaves"]
                ]
    # A lower area limit counts as many leaves or more, somewhere more.
    assert counted[1].keys() == counted[16].keys()
    assert all(counted[1][k] >= n for k, n in counted[16].items())
    assert sum(counted[1].values()) > sum(counted[16].values())


def test_target_keys_pick_the_traits_as_they_pick_the_labels(dataset):
    pytest.importorskip("torchvision")
    from plantdreamer.data import PlantViews

    keys = ["traits", "visible_fraction", "boxes", "leaf_count"]
    _, target = PlantViews(dataset, target_keys=keys)[0]
    assert list(target) == ["boxes", "visible_fraction", "leaf_count", "traits"]
    assert len(target["visible_fraction"]) == len(target["boxes"]) > 0
    assert target["traits"]["leaf_count"] > 0
    with pytest.raises(InputError, match="need boxes"):
        PlantViews(dataset, target_keys=["visible_fraction"])


def test_plants_without_traits_are_named_not_left_out_silently(dataset, tmp_path):
    import csv

    copy = tmp_path / "ds"
    shutil.copytree(dataset, copy)
    old = sorted((copy / "plants").iterdir())[0]
    (old / "traits.json").unlink()  # a plant made before traits.json was written
    result = cli("labels", copy, "--split", "2,1,0", "--allow-empty-split")
    assert result.exit_code == 0, result.output
    assert f"1 plant(s) have no traits.json ({old.name})" in result.output
    rows = []
    for split in SPLITS:
        with open(copy / "traits" / f"{split}.csv", newline="") as f:
            rows += [r["plant_id"] for r in csv.DictReader(f)]
    assert old.name not in rows and len(rows) == len(list((copy / "plants").iterdir())) - 1


def test_another_area_limit_remakes_each_plants_files(dataset):
    result = cli("labels", dataset, "--min-instance-area", "1", "--allow-empty-split")
    assert result.exit_code == 0, result.output
    for plant_id in PLANTS:
        info = json.loads((dataset / "plants" / plant_id / "coco.json").read_text())["info"]
        assert info["min_instance_area"] == 1 and info["ignore_regions"] == 0
    coco = json.loads((dataset / "coco" / "train.json").read_text())
    assert coco["info"]["min_instance_area"] == 1


def test_labels_of_one_plant_folder(dataset):
    plant = dataset / "plants" / "bean-a"
    result = cli("labels", plant, "--min-instance-area", "1")
    assert result.exit_code == 0, result.output
    assert "objects in 2 images, at most" in result.output
    assert "(0 under 1 pixels kept as ignore regions)" in result.output
    assert json.loads((plant / "coco.json").read_text())["info"]["min_instance_area"] == 1


def test_dataset_refuses_an_empty_split_before_any_plant_runs(tmp_path):
    pytest.importorskip("ray")
    ids = ["bean-s0000", "bean-s0001"]
    assert not split_plants(ids, parse_ratios("0.8,0.1,0.1"), 0)["val"]
    out = tmp_path / "ds"
    result = cli("dataset", "--species", "bean", "--count", 2, "--guidance", "none",
                 "--steps", 0, "--eval-views", 0, "--quiet", "--out", out)  # fmt: skip
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert result.output.startswith("error: split val drew no plant (1 train, 0 val, 1 test")
    assert not (out / "plants").exists() or not any((out / "plants").iterdir())


def renumber_classes(plant, order):
    """A plant folder whose class map values are permuted: value v becomes order[v - 1]."""
    import imageio.v3 as iio

    lut = np.arange(256, dtype=np.uint8)
    lut[1 : len(order) + 1] = order
    meta = json.loads((plant / "transforms.json").read_text())
    for c in meta["semantic_classes"]:
        c["value"] = int(lut[c["value"]])
    for frame in meta["frames"]:
        path = plant / frame["semantic_path"]
        iio.imwrite(path, lut[iio.imread(path)])
    (plant / "transforms.json").write_text(json.dumps(meta))


def test_categories_are_keyed_by_class_name_across_plants(dataset, tmp_path):
    from pycocotools.coco import COCO

    other = tmp_path / "mixed"
    for plant_id in ("bean-a", "mint-a"):
        shutil.copytree(dataset / "plants" / plant_id, other / "plants" / plant_id)
    renumber_classes(other / "plants" / "mint-a", [4, 3, 2, 1])  # leaf 4 ... soil 1
    result = cli("labels", other, "--split", "1,0,0")
    assert result.exit_code == 0, result.output
    assert "renumbered by class name" in result.output
    coco = COCO(str(other / "coco" / "train.json"))
    names = {c["id"]: c["name"] for c in coco.loadCats(coco.getCatIds())}
    assert sorted(names.values()) == ["leaf", "pot", "soil", "stem"]
    for ann in coco.loadAnns(coco.getAnnIds()):
        if ann["instance_id"] >= 0:  # only leaves have instances, in both plants
            assert names[ann["category_id"]] == "leaf"
    data = yaml.safe_load((other / "yolo" / "data.yaml").read_text())
    assert [data["names"][i] for i in range(4)] == [names[i] for i in sorted(names)]
    pytest.importorskip("torchvision")
    from plantdreamer.data import PlantViews

    views = PlantViews(other)
    assert views.classes == names
    for _, target in views:
        leaves = target["instance_ids"] >= 0
        assert [names[int(v)] for v in target["labels"][leaves]] == ["leaf"] * int(leaves.sum())


def test_labels_never_write_inside_a_plant_folder_outside_the_dataset(dataset, tmp_path):
    linked = tmp_path / "linked"
    (linked / "plants").mkdir(parents=True)
    (linked / "plants" / "elsewhere").symlink_to(dataset / "plants" / "bean-b")
    outside = dataset / "plants" / "bean-b"
    before = {p: p.read_bytes() for p in outside.rglob("*") if p.is_file()}
    result = cli("labels", linked, "--min-instance-area", "3", "--split", "1,0,0")
    assert result.exit_code == 0, result.output
    assert "lies outside" in result.output
    assert {p: p.read_bytes() for p in outside.rglob("*") if p.is_file()} == before
    assert (linked / "coco" / "train.json").is_file()


def test_labels_twice_leave_no_hidden_files(dataset):
    for _ in range(2):
        assert cli("labels", dataset, "--allow-empty-split").exit_code == 0
    hidden = [p for p in (dataset / "yolo").rglob(".*")]
    hidden += [p for p in (dataset / "plants").rglob(".*")]
    assert hidden == []


def test_the_summary_names_the_gallery_as_the_folder_was_typed(dataset, monkeypatch):
    monkeypatch.chdir(dataset.parent)
    result = cli("labels", dataset.name, "--allow-empty-split")
    assert result.exit_code == 0, result.output
    assert f"gallery: {dataset.name}/gallery.png" in result.output.splitlines()
    assert f"card: {dataset.name}/README.md (" in result.output
    readme = (dataset / "README.md").read_text()
    assert readme.startswith("---\n") and "\n---\n# A plantdreamer dataset\n" in readme


def test_label_maps_of_another_size_than_their_render_are_refused(dataset, tmp_path):
    import imageio.v3 as iio

    plant = shutil.copytree(dataset / "plants" / "bean-a", tmp_path / "plant")
    labels = plant / "labels" / "view_001.png"
    iio.imwrite(labels, iio.imread(labels)[::2, ::2])
    result = cli("labels", plant)
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert result.output.startswith("error: ") and str(labels) in result.output
    assert "is 32x32 px but its render" in result.output
    pytest.importorskip("torchvision")
    from plantdreamer.data import PlantViews
    from plantdreamer.errors import InputError

    with pytest.raises(InputError, match=r"labels/view_001\.png is 32x32 px"):
        PlantViews(plant)[1]


def test_stuff_classes_are_no_objects_but_stay_in_the_class_maps(dataset):
    pytest.importorskip("torchvision")
    from plantdreamer.data import PlantViews

    bad = cli("labels", dataset, "--stuff", "pot,dirt")
    assert bad.exit_code == 1 and "--stuff names no class 'dirt'" in bad.output
    every = cli("labels", dataset, "--stuff", "leaf,stem,pot,soil", "--allow-empty-split")
    assert every.exit_code == 1 and "--stuff names every class" in every.output
    result = cli("labels", dataset, "--stuff", "pot,soil", "--allow-empty-split")
    assert result.exit_code == 0, result.output
    try:
        for coco_file in [dataset / "coco" / f"{s}.json" for s in SPLITS] + [
            dataset / "plants" / p / "coco.json" for p in PLANTS
        ]:
            coco = json.loads(coco_file.read_text())
            assert [c["name"] for c in coco["categories"]] == ["leaf", "stem"], coco_file
            assert {a["category_id"] for a in coco["annotations"]} <= {1, 2}
            assert coco["info"]["stuff_classes"] == ["pot", "soil"]
        data = yaml.safe_load((dataset / "yolo" / "data.yaml").read_text())
        assert data["nc"] == 2 and data["names"] == {0: "leaf", 1: "stem"}
        views = PlantViews(dataset)  # the stuff its label files record
        assert views.classes == {1: "leaf", 2: "stem"} and views.num_classes == 3
        semantic = set()
        for _, target in views:
            assert set(target["labels"].tolist()) <= {1, 2}
            semantic |= set(target["semantic"].unique().tolist())
        assert {3, 4} <= semantic  # the class maps keep the stuff
    finally:
        assert cli("labels", dataset, "--allow-empty-split").exit_code == 0


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


# -- the exports are the dataset's own, written whole or not at all, under its lock -----------


def _copy(dataset, tmp_path):
    copy = tmp_path / "ds"
    shutil.copytree(dataset, copy)
    assert cli("labels", copy, "--allow-empty-split").exit_code == 0
    return copy


def _exports(folder):
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for name in ("splits.json", "coco", "yolo", "gallery.png")
        for p in ([folder / name] if (folder / name).is_file() else (folder / name).rglob("*"))
        if p.is_file()
    }


def test_labels_refuses_foreign_files_in_its_folders_and_links(dataset, tmp_path):
    copy = _copy(dataset, tmp_path)
    mine = copy / "yolo" / "labels" / "train" / "mine.txt"
    mine.parent.mkdir(parents=True, exist_ok=True)
    mine.write_text("a user's labels")
    result = cli("labels", copy, "--allow-empty-split")
    assert result.exit_code == 1 and "yolo/labels/train/mine.txt" in result.output, result.output
    assert mine.read_text() == "a user's labels"
    mine.unlink()
    elsewhere = tmp_path / "elsewhere"
    shutil.move(copy / "yolo", elsewhere)
    (copy / "yolo").symlink_to(elsewhere)
    before = {p: p.read_bytes() for p in elsewhere.rglob("*") if p.is_file()}
    result = cli("labels", copy, "--allow-empty-split")
    assert result.exit_code == 1 and "yolo (a link)" in result.output, result.output
    assert {p: p.read_bytes() for p in elsewhere.rglob("*") if p.is_file()} == before


def test_a_failed_export_leaves_the_previous_one_whole(dataset, tmp_path):
    copy = _copy(dataset, tmp_path)
    before = _exports(copy)
    bad = copy / "plants" / sorted(PLANTS)[-1] / "instances" / "view_001.png"
    bad.write_bytes(b"not a png")
    result = cli("labels", copy, "--split", "1,1,1", "--split-seed", 1, "--allow-empty-split")
    assert result.exit_code == 1, result.output
    assert _exports(copy) == before
    assert not [p for p in copy.iterdir() if p.name.startswith(".staging")]


def test_labels_waits_for_no_run_it_is_refused_while_one_holds_the_folder(dataset, tmp_path):
    from plantdreamer.output_folder import LOCK_NAME, locked

    copy = _copy(dataset, tmp_path)
    before = _exports(copy)
    with locked(copy / LOCK_NAME, "dataset folder", "`plantdreamer dataset`"):
        result = cli("labels", copy, "--split", "1,1,1", "--allow-empty-split")
    assert result.exit_code == 1 and "in use" in result.output, result.output
    assert _exports(copy) == before
