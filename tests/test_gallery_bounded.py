"""``gallery`` is bounded whatever the dataset's size (an even sample of the plants, panels
shrunk before drawing), reads a ``generate --seeds`` group folder, and names the file or the
cause when a plant folder cannot be shown or labelled."""

import json

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from cli_run import one_error
from plantdreamer.cli import main
from plantdreamer.exports.gallery import MAX_PLANTS, evenly

TINY = ["--guidance", "none", "--steps", "0", "--points", "300", "--resolution", "32",
        "--turntable", "none", "--quiet"]  # fmt: skip


def cli(*args):
    return CliRunner().invoke(main, [*map(str, args)])


def fake_plant(folder, seed, side=64):
    """A finished plant folder as far as the gallery reads it: run.json, one view and its
    label preview, transforms.json."""
    rng = np.random.default_rng(seed)
    for sub in ("renders", "labels/preview"):
        (folder / sub).mkdir(parents=True)
        pixels = rng.integers(0, 255, (side, side, 3), dtype=np.uint8)
        Image.fromarray(pixels).save(folder / sub / "view_000.png")
    (folder / "run.json").write_text(json.dumps({"config": {"source": {"species": "bean"}}}))
    frames = [{"file_path": "renders/view_000.png"}]
    (folder / "transforms.json").write_text(json.dumps({"frames": frames}))


def test_the_sample_is_even_distinct_and_bounded():
    for n, k in ((10_000, MAX_PLANTS), (145, 144), (7, 144), (1000, 9)):
        picks = evenly(n, k)
        assert len(picks) == min(n, k) == len(set(picks)) and picks == sorted(picks)
        assert picks[0] == 0 and picks[-1] < n
        assert max(np.diff([*picks, n])) <= -(-n // k)  # no gap wider than n / k


def test_a_dataset_larger_than_the_sheet_is_sampled(tmp_path):
    for i in range(40):
        fake_plant(tmp_path / "plants" / f"bean-s{i:04d}", i, side=300)
    out = tmp_path / "g.png"
    result = cli("gallery", tmp_path, "--out", out, "--max-plants", 9)
    assert result.exit_code == 0, result.output
    with Image.open(out) as image:  # Pillow opens it: 3 pairs a row, 3 rows and a header
        assert image.size == (6 * 180, 3 * (180 + 25) + 25)
    one_error(cli("gallery", tmp_path, "--max-plants", 0), "--max-plants")


def test_a_generate_seeds_group_folder_has_a_gallery(tmp_path):
    group = tmp_path / "g"
    result = cli("generate", "--species", "bean", "--seeds", "0,1", "--eval-views", 1, *TINY,
                 "--out", group)  # fmt: skip
    assert result.exit_code == 0, result.output
    result = cli("gallery", group, "--out", tmp_path / "g.png")
    assert result.exit_code == 0, result.output
    with Image.open(tmp_path / "g.png") as image:
        assert image.size == (4 * 180, 180 + 25)  # two plants, one row


def test_a_truncated_transforms_json_is_named(tmp_path):
    plant = tmp_path / "plant"
    fake_plant(plant, 0)
    text = (plant / "transforms.json").read_text()
    (plant / "transforms.json").write_text(text[: len(text) // 2])
    for command in ("gallery", "labels"):
        one_error(cli(command, plant), f"{plant / 'transforms.json'} is not valid JSON")
    dataset = tmp_path / "d"
    fake_plant(dataset / "plants" / "bean-s0000", 0)
    (dataset / "plants" / "bean-s0000" / "transforms.json").write_text("{")
    one_error(cli("gallery", dataset), "transforms.json is not valid JSON")


@pytest.mark.parametrize("command", ["gallery", "labels"])
def test_a_plant_made_without_views_says_so(tmp_path, command):
    plant = tmp_path / "plant"
    result = cli("generate", "--species", "bean", "--eval-views", 0, *TINY, "--out", plant)
    assert result.exit_code == 0, result.output
    one_error(cli(command, plant), "made with --eval-views 0")
