"""The exported views' backgrounds and jitter (views/): the default orbit on grey writes what
the export wrote before them, a background or a jitter changes the pictures only, a
composited pixel is alpha x render + (1 - alpha) x background, and a bad background folder
is one error before anything runs."""

import json
import shutil
import struct
import zlib

import numpy as np
import pytest
from click.testing import CliRunner

from labelled_plant import SETTINGS, make_plant
from plantdreamer.cli import main

MAPS = ("labels", "instances", "depth")


def read_png(path):
    import imageio.v3 as iio

    return np.asarray(iio.imread(path))


def write_png(path, array):
    import imageio.v3 as iio

    iio.imwrite(path, np.asarray(array, np.uint8), extension=".png")


def files(folder, sub):
    return {p.name: p.read_bytes() for p in sorted((folder / sub).glob("*.png"))}


@pytest.fixture(scope="module")
def backgrounds(tmp_path_factory):
    """Two photos of other sizes and shapes (a gradient and a checker board)."""
    folder = tmp_path_factory.mktemp("backgrounds")
    y, x = np.mgrid[0:50, 0:140]
    write_png(folder / "bench.png", np.stack([x * 1.8, y * 5, 255 - x], -1))
    board = ((np.indices((300, 200)).sum(0) // 7) % 2 * 200 + 30)[..., None]
    write_png(folder / "soil.jpg.png", np.repeat(board, 3, -1))
    return folder


@pytest.fixture(scope="module")
def plants(tmp_path_factory, backgrounds):
    """The label tests' small bean on grey, and with each kind of look."""
    root = tmp_path_factory.mktemp("looks")
    looks = {
        "grey": {},
        "colour": {"background_colour": (0.75, 0.75, 0.75)},  # the grey of --background
        "images": {"background_images": str(backgrounds)},
        "jitter": {"jitter_brightness": 0.3, "jitter_contrast": 0.2, "jitter_white_balance": 0.1},
        "rig": {"rig": "random", "background_images": str(backgrounds), "jitter_contrast": 0.2},
    }
    return {name: make_plant(root / name, **extra) for name, extra in looks.items()}


def test_the_default_orbit_writes_what_the_export_wrote_before_rigs(plants, tmp_path):
    """The export's views of d0ac9b2, remade here by its own lines (the orbit, renders on
    the grey, the writer without records) from the plant, give the same bytes."""
    import torch

    from plantdreamer.exports import write_plant_exports
    from plantdreamer.io import read_splat_ply
    from plantdreamer.pipeline import GenerateConfig, outputs
    from plantdreamer.pipeline.export import _class_names
    from plantdreamer.pipeline.model.gaussian_model import GaussianModel
    from plantdreamer.pipeline.rerender import GenerateFrame
    from plantdreamer.pipeline.truth.dataset_export import ground_truth_writer, render_views

    plant = plants["grey"]
    cfg = GenerateConfig.of(**SETTINGS)
    frame = GenerateFrame.beside(plant / "plant.ply")
    scene = frame.to_scene(read_splat_ply(plant / "plant.ply"))
    view_model = GaussianModel(scene)
    out = tmp_path / "reference"
    shutil.copy(plant / "plant.ply", tmp_path / "plant.ply")
    cameras, _ = outputs.eval_orbit(cfg.outputs, scene, cfg.train.resolution)
    writer = ground_truth_writer(out, view_model, frame.transform, True, _class_names(cfg))

    def render(camera):
        image, _, meta = view_model.render([camera], cfg.train.background)
        return outputs.to_uint8(image[0].numpy()), meta

    frames = []
    with torch.no_grad():
        render_views(view_model, writer, cameras, render, lambda _, image: frames.append(image))
    outputs.write_renders(out / "renders", frames)
    shutil.copy(plant / "plant.ply", out / "plant.ply")
    shutil.copy(plant / "traits.json", out / "traits.json")  # the views' traits, for COCO
    write_plant_exports(out)
    for sub in ("renders", *MAPS):
        assert files(plant, sub) == files(out, sub), sub
    for name in ("transforms.json", "coco.json"):
        mine = (plant / name).read_text().replace(plant.name, out.name)
        assert mine == (out / name).read_text(), name
    assert files(plant, "yolo/labels") == files(out, "yolo/labels")


@pytest.mark.parametrize("look", ["images", "jitter"])
def test_a_look_changes_the_pictures_only(plants, look):
    grey, other = plants["grey"], plants[look]
    for sub in MAPS:
        assert files(grey, sub) == files(other, sub), sub
    assert all(a != b for a, b in zip(files(grey, "renders").values(),
                                      files(other, "renders").values(), strict=True))  # fmt: skip
    before, after = (json.loads((p / "transforms.json").read_text()) for p in (grey, other))
    for a, b in zip(before["frames"], after["frames"], strict=True):
        assert a["transform_matrix"] == b["transform_matrix"]
        assert {k: v for k, v in b.items() if k not in ("background", "jitter")} == a
    key = "jitter" if look == "jitter" else "background"
    assert all(key in f for f in after["frames"])


def rendered(plant, view, background):
    """View ``view`` of a plant folder rendered anew: (colour made on ``background``,
    alpha), float32, by the rasterizer alone."""
    import torch

    from plantdreamer.io import read_splat_ply
    from plantdreamer.pipeline.model.gaussian_model import GaussianModel
    from plantdreamer.pipeline.rerender import GenerateFrame, scene_cameras

    frame = GenerateFrame.beside(plant / "plant.ply")
    scene = frame.to_scene(read_splat_ply(plant / "plant.ply"))
    camera = scene_cameras(plant, frame.transform)[view]
    with torch.no_grad():
        image, alpha, _ = GaussianModel(scene).render([camera], background)
    return image[0].numpy().astype(np.float64), alpha[0, ..., 0].numpy().astype(np.float64)


def to_uint8(x):
    return (np.clip(x, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def test_a_composited_pixel_is_alpha_render_plus_the_rest_background(plants, backgrounds):
    from PIL import Image

    plant = plants["images"]
    meta = json.loads((plant / "transforms.json").read_text())
    used = set()
    for view, frame in enumerate(meta["frames"]):
        record = frame["background"]
        used.add(record["image"])
        x, y, w, h = record["crop"]
        photo = np.asarray(Image.open(backgrounds / record["image"]).convert("RGB"), np.float32)
        scale = max(w / photo.shape[1], h / photo.shape[0])  # covers the view
        size = (max(w, round(photo.shape[1] * scale)), max(h, round(photo.shape[0] * scale)))
        cover = np.stack([np.asarray(Image.fromarray(photo[..., c] / 255).resize(size, 2))
                          for c in range(3)], -1)  # fmt: skip
        background = cover[y : y + h, x : x + w].astype(np.float64)
        on_black, alpha = rendered(plant, view, 0.0)
        want = on_black + (1.0 - alpha[..., None]) * background
        got = read_png(plant / frame["file_path"])
        assert np.abs(got.astype(int) - to_uint8(want).astype(int)).max() <= 1
        assert (got == to_uint8(want)).mean() > 0.99
        assert 0 < alpha.mean() < 1  # the view shows plant and background both


def test_a_colour_behind_the_plant_is_the_rasterizers_own_background(plants):
    """A colour composited by the views gives the bits of the rasterizer's own blend: the
    grey of --background as a colour writes the files of the grey."""
    grey, colour = plants["grey"], plants["colour"]
    for sub in ("renders", *MAPS):
        assert files(grey, sub) == files(colour, sub), sub
    frames = json.loads((colour / "transforms.json").read_text())["frames"]
    assert all(f["background"] == {"colour": [0.75, 0.75, 0.75]} for f in frames)


def test_each_jitter_is_written_beside_its_view_and_is_what_was_applied(plants):
    plant = plants["jitter"]
    meta = json.loads((plant / "transforms.json").read_text())
    seen = []
    for view, frame in enumerate(meta["frames"]):
        j = frame["jitter"]
        assert 0.7 <= j["brightness"] <= 1.3 and 0.8 <= j["contrast"] <= 1.2
        assert all(0.9 <= g <= 1.1 for g in j["white_balance"])
        seen.append(j["brightness"])
        image, _ = rendered(plant, view, SETTINGS.get("background", 0.75))
        gained = image * np.asarray(j["white_balance"]) * j["brightness"]
        want = to_uint8(0.5 + j["contrast"] * (gained - 0.5))
        got = read_png(plant / frame["file_path"])
        assert np.abs(got.astype(int) - want.astype(int)).max() <= 1
    assert len(set(seen)) == len(seen)  # drawn per view


def huge_png(path, width, height):
    """A PNG whose header claims ``width`` x ``height`` pixels (no pixel data behind it)."""

    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IEND", b""))


GEN = ["generate", "--species", "bean", "--guidance", "none", "--steps", "0", "--points",
       "300", "--resolution", "16", "--eval-views", "1", "--turntable", "none", "--quiet"]  # fmt: skip


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ("notes.txt", "notes.txt cannot be read as an image"),
        ("huge.png", "above the limit"),
        ("cut.png", "cut.png cannot be read as an image"),
        ("empty", "holds no image"),
        ("missing", "is not a folder"),
    ],
)
def test_a_bad_background_folder_is_one_error_before_anything_runs(tmp_path, bad, message):
    folder = tmp_path / "photos"
    folder.mkdir()
    write_png(folder / "good.png", np.zeros((8, 8, 3)))
    if bad == "notes.txt":
        (folder / bad).write_text("not a picture")
    elif bad == "huge.png":
        huge_png(folder / bad, 9000, 9000)
    elif bad == "cut.png":
        write_png(folder / bad, np.full((64, 64, 3), 90))
        (folder / bad).write_bytes((folder / bad).read_bytes()[:80])
    elif bad == "empty":
        (folder / "good.png").unlink()
    else:
        folder = tmp_path / "missing"
    out = tmp_path / "out"
    result = CliRunner().invoke(main, [*GEN, "--out", str(out), "--background-images",
                                       str(folder)])  # fmt: skip
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert result.exit_code == 1 and len(errors) == 1, result.output
    assert message in errors[0] and "Traceback" not in result.output
    assert not out.exists()


def test_render_remakes_a_rigs_views_bit_for_bit(plants, tmp_path):
    """`render --labels` of a plant made with a drawn rig, photos and jitter reads them (and
    the seed) from its run.json: generate's views and ground truth, byte for byte."""
    plant, out = plants["rig"], tmp_path / "again"
    result = CliRunner().invoke(main, ["render", str(plant), "--labels", "--out", str(out)])
    assert result.exit_code == 0, result.output
    for sub in ("renders", *MAPS):
        assert files(plant, sub) == files(out, sub), sub
    mine = json.loads((plant / "transforms.json").read_text())
    again = json.loads((out / "transforms.json").read_text())
    assert mine["frames"] == again["frames"] and "rig" in mine["frames"][0]
    # The cameras written lie in the random rig's ranges (seen from the plant's centre).
    centre = np.asarray(json.loads((plant / "run.json").read_text())["transform"]["center"])
    for frame in mine["frames"]:
        offset = np.asarray(frame["transform_matrix"])[:3, 3] - centre
        elevation = np.degrees(np.arcsin(offset[2] / np.linalg.norm(offset)))
        fovy = np.degrees(
            2 * np.arctan(frame.get("h", mine["h"]) / 2 / frame.get("fl_y", mine["fl_y"]))
        )
        assert -1e-6 <= elevation <= 90 + 1e-6 and 30 - 1e-6 <= fovy <= 70 + 1e-6
    # Its views at a transforms.json's cameras are on the grey; a look typed there is refused.
    typed = CliRunner().invoke(main, ["render", str(plant), "--transforms", str(plant),
                                      "--out", str(tmp_path / "t"), "--rig", "side"])  # fmt: skip
    assert typed.exit_code == 1 and "not with --rig" in typed.output
