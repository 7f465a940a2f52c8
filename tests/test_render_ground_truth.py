"""``render`` remakes generate's views and ground truth: at a transforms.json's cameras, and on
generate's own orbit when given a plant folder."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from labelled_plant import make_plant
from plantdreamer.cli import main

FOLDERS = ("renders", "labels", "instances", "depth")


def read_png(path):
    import imageio.v3 as iio

    return np.asarray(iio.imread(path))


def render(*args):
    result = CliRunner().invoke(main, ["render", *map(str, args)])
    assert result.exit_code == 0, result.output
    return result


def assert_same_views(a, b, count):
    for folder in FOLDERS:
        names = sorted(p.name for p in (b / folder).glob("view_*.png"))
        assert len(names) == count
        assert sorted(p.name for p in (a / folder).glob("view_*.png")) == names
        for name in names:
            np.testing.assert_array_equal(read_png(a / folder / name), read_png(b / folder / name))


def test_labels_at_generates_cameras_are_bit_for_bit(bean, tmp_path):
    render(bean / "plant.ply", "--labels", "--transforms", bean / "transforms.json",
           "--out", tmp_path / "v")  # fmt: skip
    assert_same_views(tmp_path / "v", bean, 3)
    ours = json.loads((tmp_path / "v" / "transforms.json").read_text())
    theirs = json.loads((bean / "transforms.json").read_text())
    for a, b in zip(ours["frames"], theirs["frames"], strict=True):
        assert a.keys() == b.keys() and a["file_path"] == b["file_path"]
        # The same camera (the pose went through the scene frame and back: float64 rounding).
        np.testing.assert_allclose(a["transform_matrix"], b["transform_matrix"], atol=1e-12)
    # Class names come from plant.ply's header, not "class 1..4".
    assert ours["semantic_classes"] == theirs["semantic_classes"]
    assert [c["name"] for c in ours["semantic_classes"]] == ["leaf", "stem", "pot", "soil"]
    assert json.loads((tmp_path / "v" / "coco.json").read_text())["annotations"]


def test_a_plant_folder_renders_on_generates_orbit(bean, tmp_path):
    render(bean, "--labels", "--out", tmp_path / "o")
    assert_same_views(tmp_path / "o", bean, 3)
    # Settings given on the command line still win.
    render(bean, "--resolution", "40", "--turntable", "none", "--out", tmp_path / "small")
    assert read_png(tmp_path / "small" / "view_002.png").shape == (40, 40, 3)
    assert not (tmp_path / "small" / "view_003.png").exists()


def test_the_orbit_distance_is_generates_framed_or_given(bean, tmp_path):
    """generate frames its orbit on the plant and records the distance; render uses it, and
    frames a plant generated without views by the same rule (the same views, bit for bit)."""
    run = json.loads((bean / "run.json").read_text())
    assert run["config"]["eval-distance"] is None and 1.0 < run["outputs"]["eval_distance"] < 8.0
    plant = make_plant(tmp_path / "none", eval_views=0)
    assert json.loads((plant / "run.json").read_text())["outputs"]["eval_distance"] is None
    render(plant, "--labels", "--eval-views", 3, "--out", tmp_path / "o")
    assert_same_views(tmp_path / "o", bean, 3)
    # A distance given to generate is kept, and render follows it.
    far = make_plant(tmp_path / "far", eval_distance=9.0)
    assert json.loads((far / "run.json").read_text())["outputs"]["eval_distance"] == 9.0
    render(far, "--labels", "--out", tmp_path / "f")
    assert_same_views(tmp_path / "f", far, 3)


def test_labels_at_cameras_for_a_ply_without_run_json(bean, tmp_path):
    """Another tool's PLY: rendered in its own frame, close to (not bit for bit) generate's."""
    (tmp_path / "alone").mkdir()
    shutil.copy(bean / "plant.ply", tmp_path / "alone" / "model.ply")
    render(tmp_path / "alone" / "model.ply", "--labels", "--transforms",
           bean / "transforms.json", "--out", tmp_path / "v")  # fmt: skip
    for i in range(3):
        a = read_png(tmp_path / "v" / "labels" / f"view_{i:03d}.png")
        b = read_png(bean / "labels" / f"view_{i:03d}.png")
        assert (a == b).mean() > 0.99


@pytest.mark.slow
def test_a_trained_plant_is_reproduced_bit_for_bit(tmp_path):
    """After density control the plant's float32 positions in plant.ply are not generate's
    scene positions scaled back exactly; generate renders what the file holds, so a re-render
    still matches (before it did, 1-pixel differences showed in depth and colour here)."""
    plant = make_plant(
        tmp_path / "kale", species="kale", seed=5, steps=700, points=4000, resolution=128,
        eval_views=6,
    )  # fmt: skip
    render(plant, "--labels", "--transforms", plant / "transforms.json", "--out", tmp_path / "v")
    assert_same_views(tmp_path / "v", plant, 6)


def test_a_plant_cut_to_sh_degree_0_is_reproduced_too(tmp_path):
    """Trained at SH degree 3 and written at degree 0: generate's views show what the file
    holds (degree 0), so a re-render still matches."""
    import torch

    from labelled_plant import SETTINGS
    from plantdreamer.guidance.base import PhotometricGuidance
    from plantdreamer.pipeline import GenerateConfig, generate_plants

    target = torch.full((1, 64, 64, 3), 0.3)
    target[..., 1] = 0.7
    cfg = GenerateConfig.of(
        **{**SETTINGS, "resolution": 64, "steps": 30, "sh_degree": 3, "sh_degree_export": 0}
    )
    plant = tmp_path / "bean"
    generate_plants([cfg], plant, guidance=PhotometricGuidance(target), show_progress=False)
    render(plant, "--labels", "--out", tmp_path / "v")
    assert_same_views(tmp_path / "v", plant, 3)
