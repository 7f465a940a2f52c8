"""Scenes of finished plants (scenes/, dataset/scenes.py): a tray of four plants rendered in
one pass keeps every instance id unique, shows each plant where it is frontmost (against
each plant rendered alone, with depth), and its label files are read by pycocotools and
Ultralytics with one object per visible leaf; a dataset's scenes take the plants of one
split and join its COCO, YOLO and PlantViews."""

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
from click.testing import CliRunner

from labelled_plant import make_plant
from plantdreamer.errors import InputError

PLANT_SEEDS = (1, 2, 3, 4)
SCENE = dict(eval_views=2, resolution=128, rig="side", rig_elevation_deg=(20.0, 35.0),
             rig_distance=(1.0, 1.0), seed=7)  # fmt: skip


def read_png(path):
    import imageio.v3 as iio

    return np.asarray(iio.imread(path))


@pytest.fixture(scope="module")
def plants(tmp_path_factory):
    root = tmp_path_factory.mktemp("scene_plants")
    return [make_plant(root / f"bean-s{s:04d}", seed=s, eval_views=1) for s in PLANT_SEEDS]


@pytest.fixture(scope="module")
def tray(plants, tmp_path_factory):
    from plantdreamer.scenes import make_scene

    out = tmp_path_factory.mktemp("tray") / "tray"
    result = make_scene(plants, out, **SCENE)
    assert (result.plants, result.views) == (4, 2)
    return out


def test_every_instance_of_the_tray_has_an_id_of_its_own(plants, tray):
    from plantdreamer.io import read_splat_ply

    record = json.loads((tray / "scene.json").read_text())
    meta = json.loads((tray / "transforms.json").read_text())
    ids = [e["instance"] for e in meta["instance_ids"]]
    values = [e["value"] for e in meta["instance_ids"]]
    assert len(set(ids)) == len(ids) and len(set(values)) == len(values)
    expected = set()
    for plant, entry in zip(plants, record["plants"], strict=True):
        own = read_splat_ply(plant / "plant.ply").labels[:, 1]
        expected |= {int(i) + entry["instance_offset"] for i in np.unique(own[own >= 0])}
    assert set(ids) == expected
    value_to_id = dict(zip(values, ids, strict=True))
    for frame in meta["frames"]:
        instance = read_png(tray / frame["instance_path"])
        plant_map = read_png(tray / frame["plant_path"])
        for value in np.unique(instance[instance > 0]):
            owners = np.unique(plant_map[instance == value])
            assert len(owners) == 1 and owners[0] > 0  # one instance: one plant's
            k = owners[0] - 1
            offsets = [e["instance_offset"] for e in record["plants"]] + [10**9]
            assert offsets[k] <= value_to_id[int(value)] < offsets[k + 1]
        assert len(np.unique(plant_map)) == 5  # background and the four plants


def alone_and_together(plants, tray):
    """Per view: each plant rendered alone at its place (class index map, depth) and the
    tray's written class and plant maps."""
    import torch

    from plantdreamer.pipeline.export import export_plan
    from plantdreamer.pipeline.model.gaussian_model import GaussianModel
    from plantdreamer.pipeline.truth.ground_truth import LabelSet, render_ground_truth
    from plantdreamer.scenes.compose import compose, read_plant
    from plantdreamer.scenes.make import scene_settings
    from plantdreamer.scenes.render import scene_frame

    record = json.loads((tray / "scene.json").read_text())
    meta = json.loads((tray / "transforms.json").read_text())
    read = [read_plant(p) for p in plants]
    places = np.array([e["place"][:2] for e in record["plants"]])
    _, cfg = scene_settings(record["settings"])
    composed = compose(read, places)
    transform = scene_frame(composed, cfg.source.scene_size)
    cameras = export_plan(cfg, transform.gaussians_to_scene(composed.gaussians, composed.means))
    cameras = cameras.cameras
    for camera, frame in zip(cameras, meta["frames"], strict=True):  # the tray's cameras
        c2w = camera.to_opengl_c2w()
        c2w[:3, 3] = transform.invert(c2w[:3, 3][None])[0]
        np.testing.assert_allclose(c2w, frame["transform_matrix"], atol=1e-9)
    views = []
    for camera, frame in zip(cameras, meta["frames"], strict=True):
        alone = []
        for k in range(len(read)):
            one = compose([read[k]], places[k : k + 1])
            g = transform.gaussians_to_scene(one.gaussians, one.means)
            labels = LabelSet.of(g.labels)
            with torch.no_grad():
                gt = render_ground_truth(GaussianModel(g), camera, labels)
            classes = np.where(gt.label >= 0, np.r_[labels.classes, 0][gt.label], 0)
            depth = np.where(gt.label >= 0, gt.depth, np.inf)
            alone.append((classes, depth))
        together = (read_png(tray / frame["semantic_path"]), read_png(tray / frame["plant_path"]))
        views.append((alone, together))
    return views


def interior(mask):
    """The pixels of ``mask`` whose 8 neighbours are in it too."""
    padded = np.pad(mask, 1)
    h, w = mask.shape
    return np.logical_and.reduce([padded[y : y + h, x : x + w] for y in range(3) for x in range(3)])


def test_each_plant_shows_in_the_class_map_where_it_is_frontmost(plants, tray):
    occluded = 0
    for alone, (semantic, plant_map) in alone_and_together(plants, tray):
        depth = np.stack([d for _, d in alone])
        classes = np.stack([c for c, _ in alone])
        order = np.sort(depth, axis=0)
        front = np.argmin(depth, axis=0)
        seen = np.isfinite(order[0])
        # Frontmost by a clear margin (or alone there), inside that plant's own silhouette.
        with np.errstate(invalid="ignore"):  # inf - inf where no plant is: not clear
            clear = seen & ((order[1] - order[0]) > 0.05 * np.max(order[0][seen]))
        clear &= interior(np.isfinite(np.take_along_axis(depth, front[None], 0)[0]))
        assert clear.sum() > 500
        k_map = plant_map.astype(int) - 1
        want = np.take_along_axis(classes, front[None], 0)[0]
        assert (k_map[clear] == front[clear]).mean() > 0.97
        assert (semantic[clear] == want[clear]).mean() > 0.95
        # Plants stand in each other's way in these views: the check is not trivial.
        behind = np.isfinite(order[1]) & clear
        occluded += int(behind.sum())
    assert occluded > 100


def test_pycocotools_reads_one_object_per_visible_leaf_of_the_tray(tray):
    from pycocotools import mask as mask_utils
    from pycocotools.coco import COCO

    coco = COCO(str(tray / "coco.json"))
    meta = json.loads((tray / "transforms.json").read_text())
    leaf = next(c["value"] for c in meta["semantic_classes"] if c["name"] == "leaf")
    for image_id, frame in enumerate(meta["frames"], 1):
        semantic = read_png(tray / frame["semantic_path"])
        instance = read_png(tray / frame["instance_path"])
        visible = set(np.unique(instance[(semantic == leaf) & (instance > 0)]).tolist())
        anns = coco.loadAnns(coco.getAnnIds(imgIds=[image_id]))
        leaves = [a for a in anns if a["category_id"] == leaf]
        values = {e["instance"]: e["value"] for e in meta["instance_ids"]}
        assert sorted(values[a["instance_id"]] for a in leaves) == sorted(visible)
        for a in leaves:
            m = mask_utils.decode(a["segmentation"]).astype(bool)
            assert (instance[m] == values[a["instance_id"]]).all()


@pytest.mark.slow  # Ultralytics' import in a process of its own: ~10 s
def test_ultralytics_reads_the_trays_objects(tray, tmp_path):
    if importlib.util.find_spec("ultralytics") is None:
        pytest.skip("ultralytics is not installed (the dev extra has it)")
    yolo = shutil.copytree(tray / "yolo", tmp_path / "yolo")
    out = tmp_path / "read.pkl"
    env = {**os.environ, "YOLO_CONFIG_DIR": str(tmp_path / "settings"), "YOLO_OFFLINE": "1"}
    reader = Path(__file__).with_name("ultralytics_reader.py")
    args = [sys.executable, str(reader), str(out), str(yolo / "data.yaml"), "train"]
    done = subprocess.run(args, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    read = pickle.loads(out.read_bytes())
    assert read["network_calls"] == []
    (result,) = read["results"].values()
    coco = json.loads((tray / "coco.json").read_text())
    for view in result["images"]:
        image = next(i for i in coco["images"] if i["file_name"].endswith(Path(view["file"]).name))
        objects = [a for a in coco["annotations"] if a["image_id"] == image["id"]
                   and not a["iscrowd"]]  # fmt: skip
        assert [a["category_id"] - 1 for a in objects] == view["classes"]
        leaves = [a for a in objects if a["category_id"] == 1]
        assert len({a["instance_id"] for a in leaves}) == len(leaves) > 10


def test_a_random_tray_keeps_its_plants_apart_and_repeats_with_its_seed():
    from plantdreamer.scenes.layout import tray_positions

    def places(seed):
        return tray_positions(9, "random", 0.3, np.random.default_rng(seed))

    a, b, c = places(1), places(1), places(2)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    gaps = np.hypot(*(a[:, None] - a[None]).transpose(2, 0, 1))
    assert gaps[~np.eye(9, dtype=bool)].min() >= 0.3
    grid = tray_positions(4, "grid", 0.5, np.random.default_rng(0))
    np.testing.assert_allclose(sorted(map(tuple, grid)),
                               [(-0.25, -0.25), (-0.25, 0.25), (0.25, -0.25), (0.25, 0.25)])  # fmt: skip


def test_a_scene_refuses_training_settings_and_unlabelled_plants(plants, tmp_path):
    from plantdreamer.scenes import make_scene

    with pytest.raises(InputError, match="steps: not a setting of a scene"):
        make_scene(plants, tmp_path / "a", steps=10)
    with pytest.raises(InputError, match="scene layout must be one of grid, random"):
        make_scene(plants, tmp_path / "b", scene_layout="spiral")
    with pytest.raises(InputError, match="not a finished plant folder"):
        make_scene([tmp_path], tmp_path / "c")


def dataset_of(plants, root):
    for plant in plants:
        shutil.copytree(plant, root / "plants" / plant.name)
    return root


@pytest.mark.slow  # four scenes and a dataset's exports: ~5 s
def test_a_datasets_scenes_take_one_splits_plants_and_join_its_files(plants, tmp_path):
    from plantdreamer.data import PlantViews
    from plantdreamer.dataset.scenes import expand_scenes, make_dataset_scenes
    from plantdreamer.exports import LabelOptions, write_dataset_exports
    from plantdreamer.exports.splits import split_of

    root = dataset_of(plants, tmp_path / "ds")
    spec = {
        "defaults": {"steps": 5, "rig": "top-down", "resolution": 64},
        "scene": [{"name": "tray", "seeds": "0-3", "scene-plants": 2, "eval-views": 1}],
    }
    scenes = expand_scenes(spec)
    assert [s.id for s in scenes] == [f"tray-s000{i}" for i in range(4)]
    ratios = (0.5, 0.5, 0.0)
    plant_ids = [p.name for p in plants]
    seed = next(  # a seed that gives both splits plants and scenes
        s
        for s in range(500)
        if {split_of(i, ratios, s) for i in plant_ids} == {"train", "val"}
        and {split_of(x.id, ratios, s) for x in scenes} == {"train", "val"}
    )
    options = LabelOptions(ratios=ratios, seed=seed, allow_empty_split=True)
    assert make_dataset_scenes(root, scenes, options) == []
    labels = write_dataset_exports(root, options)
    recorded = json.loads((root / "splits.json").read_text())["scenes"]
    assert labels.scenes == recorded
    for scene in scenes:
        record = json.loads((root / "scenes" / scene.id / "scene.json").read_text())
        split = record["split"]
        assert scene.id in recorded[split] and split == split_of(scene.id, ratios, seed)
        assert all(split_of(p, ratios, seed) == split for p in record["plant_ids"])
        assert record["settings"]["rig"] == "top-down" and record["settings"]["resolution"] == 64
    for split, ids in labels.splits.items():
        if not ids:
            continue
        coco = json.loads((root / "coco" / f"{split}.json").read_text())
        names = {i["id"]: i["file_name"] for i in coco["images"]}
        in_scenes = [n for n in names.values() if n.startswith("scenes/")]
        assert len(in_scenes) == len(recorded[split])
        views = PlantViews(root, split=split)
        assert sorted(int(views[i][1]["image_id"]) for i in range(len(views))) == sorted(names)
        yolo = sorted(p.stem for p in (root / "yolo" / "images" / split).glob("tray-*"))
        assert yolo == [f"{s}__view_000" for s in recorded[split]]
    # The card says how the views and scenes were made.
    card = json.loads((root / "dataset.json").read_text())["card"]["distributions"]
    assert card["cameras"] == {"orbit: 1 views at elevation 15 deg, field of view 70 deg": 4}
    assert card["backgrounds"] == {"grey 0.75": 4} and card["jitter"] == {"off": 4}
    assert card["scenes"]["count"] == 4 and card["scenes"]["layouts"] == {"2 plants, grid": 4}
    readme = (root / "README.md").read_text()
    assert "## Distributions" in readme and "- scenes: 4 (" in readme and "Limits:" in readme
    # Made again with the same settings and plants: kept as they are.
    stamp = {s.id: (root / "scenes" / s.id / "scene.json").stat().st_mtime_ns for s in scenes}
    make_dataset_scenes(root, scenes, options)
    assert stamp == {s.id: (root / "scenes" / s.id / "scene.json").stat().st_mtime_ns
                     for s in scenes}  # fmt: skip


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"name": "../x"}, "name '../x'"),
        ({"seed": 3}, "give 'seeds'"),
        ({"lr-means": 0.1}, "lr-means: not a setting of a scene"),
        ({"scene-spacing": -1.0}, "scene-spacing must be in"),
        ({"rig": "side", "rig-distance": [2.0, 1.0]}, "rig-distance is a range"),
    ],
)
def test_a_bad_scene_table_is_refused_before_anything_runs(table, message):
    from plantdreamer.dataset.scenes import expand_scenes

    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(".", r"\.")):
        expand_scenes({"scene": [table]})


def test_dataset_scenes_options_are_checked_and_planned_before_ray(tmp_path):
    from plantdreamer.cli import main

    args = ["dataset", "--species", "bean", "--seeds", "0-3", "--out", str(tmp_path / "ds"),
            "--dry-run", "--allow-empty-split"]  # fmt: skip
    result = CliRunner().invoke(main, [*args, "--scenes", "0-1", "--scene-plants", "2"])
    assert result.exit_code == 0, result.output
    assert "then 2 scenes of the finished plants" in result.output
    result = CliRunner().invoke(main, [*args, "--scene-plants", "2"])
    assert result.exit_code == 1 and "error: --scene-plants describes the scenes" in result.output


def test_the_cards_camera_line_gives_the_ranges_a_plant_was_drawn_from():
    from plantdreamer.exports.distributions import background_text, camera_text, jitter_text

    drawn = {"rig": "top-down", "rig-distance": [1.0, 2.0], "eval-views": 8, "eval-fovy-deg": 50}
    assert camera_text(drawn) == (
        "top-down: 8 views, elevation 90 deg, azimuth -180 to 180 deg, distance 1 to 2 "
        "framed, roll 0 deg, field of view 50 deg"
    )
    assert camera_text({}) == "orbit: 120 views at elevation 15 deg, field of view 70 deg"
    assert background_text({"background-images": "/data/photos/bench"}) == (
        "photos from bench/, one per view"
    )
    assert jitter_text({"jitter-brightness": 0.2, "jitter-white-balance": 0.05}) == (
        "brightness +-0.2, white balance +-0.05"
    )


def test_plants_made_before_the_views_settings_keep_their_config_hash():
    """A dataset's plant at the default views hashes as before the views' section existed
    (its manifest still matches: no rerun), and a rig makes another plant."""
    from plantdreamer.dataset.plant import config_hash
    from plantdreamer.pipeline import GenerateConfig

    cfg = GenerateConfig.of(species="bean", steps=20, points=2000)
    # The hash d0ac9b2's config_hash gave this config (no views' or watching settings then).
    assert config_hash(cfg) == "fe63f5aaa6d5247a"
    for other in ({"rig": "top-down"}, {"jitter_contrast": 0.1}):
        assert config_hash(GenerateConfig.of(species="bean", steps=20, points=2000, **other)) != (
            config_hash(cfg)
        )
